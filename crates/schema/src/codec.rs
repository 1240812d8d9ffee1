//! The gRPC codec: prost's, except that a request that does not decode is the caller's
//! fault — INVALID_ARGUMENT naming the field it breaks, logged and counted — where tonic answers
//! INTERNAL, which reads as our bug and goes unseen.

use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};

use tonic::codec::{BufferSettings, Codec, DecodeBuf, Decoder};
use tonic::{Code, Status};
use tonic_prost::{ProstCodec, ProstDecoder, ProstEncoder};

/// Messages that did not decode since the process started (a metric).
static MALFORMED: AtomicU64 = AtomicU64::new(0);

/// How many received messages did not decode.
pub fn malformed_messages() -> u64 {
    MALFORMED.load(Ordering::Relaxed)
}

/// [`ProstCodec`] with decode errors as INVALID_ARGUMENT.
#[derive(Debug, Clone)]
pub struct InputCodec<T, U>(ProstCodec<T, U>);

impl<T, U> Default for InputCodec<T, U> {
    fn default() -> Self {
        InputCodec(ProstCodec::default())
    }
}

impl<T, U> Codec for InputCodec<T, U>
where
    T: prost::Message + Send + 'static,
    U: prost::Message + Default + Send + 'static,
{
    type Encode = T;
    type Decode = U;
    type Encoder = ProstEncoder<T>;
    type Decoder = InputDecoder<U>;

    fn encoder(&mut self) -> Self::Encoder {
        self.0.encoder()
    }

    fn decoder(&mut self) -> Self::Decoder {
        InputDecoder(self.0.decoder(), PhantomData)
    }
}

/// The decoder of [`InputCodec`].
#[derive(Debug)]
pub struct InputDecoder<U>(ProstDecoder<U>, PhantomData<U>);

impl<U> Decoder for InputDecoder<U>
where
    U: prost::Message + Default + Send + 'static,
{
    type Item = U;
    type Error = Status;

    fn decode(&mut self, buf: &mut DecodeBuf<'_>) -> Result<Option<U>, Status> {
        self.0.decode(buf).map_err(|status| {
            if status.code() != Code::Internal {
                return status;
            }
            MALFORMED.fetch_add(1, Ordering::Relaxed);
            let error = super::protobuf_error("request", &status.message());
            tracing::info!(transport = "grpc", code = ?Code::InvalidArgument, error = %error, "malformed message");
            error.to_status()
        })
    }

    fn buffer_settings(&self) -> BufferSettings {
        self.0.buffer_settings()
    }
}
