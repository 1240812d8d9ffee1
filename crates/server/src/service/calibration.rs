//! The Calibrate use case: the rig's cameras from images of a pattern or from
//! correspondences, on the compute pool like Match.

use std::time::{Duration, Instant};

use super::{Service, ServiceError};
use trinocular_core::checkpoint::Checkpoint;
use trinocular_core::extract::DecodeLimits;
use trinocular_schema::{self as api, pb, InputError};

impl Service {
    /// Calibrate, recorded under `transport`. `read` produces the request on the compute
    /// pool (so an HTTP body is parsed there); past `timeout` the answer is
    /// DEADLINE_EXCEEDED and a queued job never runs.
    pub async fn calibrate(
        &self,
        read: impl FnOnce() -> Result<pb::CalibrateRequest, InputError> + Send + 'static,
        timeout: Option<Duration>,
        transport: &str,
    ) -> Result<pb::CalibrateResponse, ServiceError> {
        let start = Instant::now();
        let limits = DecodeLimits {
            max_bytes: self.limits.max_message_bytes,
            max_pixels: self.limits.max_image_pixels,
        };
        let working = std::sync::Arc::clone(&self.working);
        let job = self.pool.run(move |abandoned| -> Result<_, ServiceError> {
            let stop = || abandoned.is_set();
            let request = read()?;
            let pixels = match &request.input {
                Some(pb::calibrate_request::Input::Images(triplet)) => {
                    api::triplet_pixels(triplet, &limits, |_| None)
                }
                _ => 0,
            };
            let _reserved = super::reserve(&working, super::memory::estimate(pixels, 0), "images")?;
            Ok(api::calibrate::calibrate_request(&request, &limits)?
                .run_until(Checkpoint::new(&stop))?)
        });
        let result = super::within(job, self.deadline(timeout)).await;
        self.observe(transport, "calibrate", start, &result);
        result
    }
}
