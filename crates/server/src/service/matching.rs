//! Running a checked `MatchRequest` ([`MatchInput`], from the schema's conversion) through the
//! pipeline on the calling thread, and why it may give no answer ([`RunError`]).
//!
//! The service calls it inside a compute-pool job ([`Service::match_request`]); the CLI, the
//! examples and the tests call it directly. The schema only converts: what runs the pipeline
//! lives here, beside the use cases.
//!
//! [`Service::match_request`]: super::Service::match_request

use trinocular_core::pipeline::{self, Checkpoint, MatchError};
use trinocular_schema::{match_error, match_response, pb, InputError, MatchInput, MatchSource};

/// What running a [`MatchInput`] produced: the pipeline's output, and from images what was
/// extracted from each.
pub use trinocular_core::pipeline::Matched as Executed;

/// Why running a [`MatchInput`] produced no answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RunError {
    /// The input cannot be matched; names the field.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The checkpoint stopped the pipeline: nobody wants the answer any more.
    #[error("stopped before {stage}: the result is no longer wanted")]
    Stopped { stage: &'static str },
}

impl From<MatchError> for RunError {
    fn from(e: MatchError) -> RunError {
        match match_error(e) {
            Ok(input) => RunError::Input(input),
            Err(stage) => RunError::Stopped { stage },
        }
    }
}

/// Running a [`MatchInput`]: a trait because the input is the schema's type and the running
/// is this crate's.
pub trait RunMatch {
    /// Runs the pipeline on this input, or reports an input error naming the field.
    fn execute(&self) -> Result<Executed, RunError> {
        self.execute_until(Checkpoint::NEVER)
    }

    /// [`RunMatch::execute`], stopping between stages when `checkpoint` says so.
    fn execute_until(&self, checkpoint: Checkpoint) -> Result<Executed, RunError>;

    /// The response to this input for what [`RunMatch::execute`] produced: the extracted
    /// lists are included when the request asked for them.
    fn response(&self, executed: &Executed) -> pb::MatchResponse;

    /// [`RunMatch::execute`], then [`RunMatch::response`].
    fn run(&self) -> Result<pb::MatchResponse, RunError> {
        self.run_until(Checkpoint::NEVER)
    }

    /// [`RunMatch::execute_until`], then [`RunMatch::response`].
    fn run_until(&self, checkpoint: Checkpoint) -> Result<pb::MatchResponse, RunError> {
        Ok(self.response(&self.execute_until(checkpoint)?))
    }
}

impl RunMatch for MatchInput {
    fn execute_until(&self, checkpoint: Checkpoint) -> Result<Executed, RunError> {
        let input = match &self.source {
            MatchSource::Segments(lists) => pipeline::Input::lists(lists),
            MatchSource::Images([a, b, c]) => pipeline::Input::Images([a, b, c]),
        };
        let options = pipeline::Options {
            params: self.params.clone(),
            extract: self.extract.clone(),
            checkpoint,
        };
        Ok(pipeline::run(&self.rig, input, &options)?)
    }

    fn response(&self, executed: &Executed) -> pb::MatchResponse {
        let extracted = executed
            .extracted
            .as_ref()
            .filter(|_| self.return_extracted);
        match_response(&executed.output, extracted)
    }
}
