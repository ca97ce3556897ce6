//! What the pipeline's errors tell a front end: [`PipelineError::hint`], the kind of problem
//! and the option it is about (`crate::error`), from which the command line, the Python module
//! and the ParaView plugin each word their own advice.

use crate::error::{ErrorKind, Hint};
use crate::optimize::driver::OutputError;
use crate::pipeline::PipelineError;
use crate::volume::VolumeError;

impl PipelineError {
    /// What a front end needs to word its advice: the hint of the stage that failed.
    pub fn hint(&self) -> Hint {
        match self {
            PipelineError::Volume(e) => volume_hint(e),
            PipelineError::Clip(e) => e.hint(),
            PipelineError::Memory(e) => e.hint(),
            PipelineError::Optimize(e) => e.hint(),
            PipelineError::Image(e) => e.hint(),
            PipelineError::Camera(e) => e.hint(),
            PipelineError::Format(e) => e.hint(),
            PipelineError::Output(OutputError::Folder { .. }) => Hint::new(ErrorKind::Io),
            PipelineError::Output(OutputError::Image(e)) => e.hint(),
            PipelineError::Output(_) => Hint::other(),
            PipelineError::Fs(e) => e.hint(),
            PipelineError::Job(_) => Hint::new(ErrorKind::InvalidOption),
            #[allow(unreachable_patterns)]
            _ => Hint::other(),
        }
    }
}

/// A volume error's hint: a file the system could not read, or one that is not a volume t2tf
/// reads.
pub fn volume_hint(e: &VolumeError) -> Hint {
    match e {
        VolumeError::Io { .. } => Hint::new(ErrorKind::Io),
        _ => Hint::new(ErrorKind::Volume),
    }
}
