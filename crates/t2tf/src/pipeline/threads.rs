//! The worker threads of a run, decided once for every front end (CLI, Python): at least one,
//! at most the logical CPUs.

use super::PipelineError;
use crate::optimize::OptimizeError;

/// A run's thread pool.
pub struct Workers {
    /// The pool the run is installed in.
    pub pool: rayon::ThreadPool,
    /// `Some((asked, used))` when more threads were asked for than there are logical CPUs
    /// (more only adds switching): the front end says so, in its own words.
    pub capped: Option<(usize, usize)>,
}

/// Whether `threads` workers can be had: 0 cannot (checked before any work; [`workers`]
/// checks it too).
pub fn check_threads(threads: Option<usize>) -> Result<(), PipelineError> {
    match threads {
        Some(0) => Err(OptimizeError::Setting {
            name: "threads",
            message: "must be at least 1".to_string(),
        }
        .into()),
        _ => Ok(()),
    }
}

/// A pool of `threads` workers (`None`: one per logical CPU); 0 is refused, more than the
/// CPUs are capped.
pub fn workers(threads: Option<usize>) -> Result<Workers, PipelineError> {
    check_threads(threads)?;
    let (n, capped) = match threads {
        Some(t) => {
            let (n, capped) = crate::memory::thread_count(t);
            (n, capped.then_some((t, n)))
        }
        None => (0, None),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(|e| PipelineError::Job(format!("cannot start the thread pool: {e}")))?;
    Ok(Workers { pool, capped })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_is_refused_and_too_many_are_capped() {
        let e = workers(Some(0)).err().expect("0 threads accepted");
        assert!(
            e.to_string().contains("`threads`: must be at least 1"),
            "{e}"
        );
        assert_eq!(e.hint(), crate::error::Hint::invalid("threads"));
        assert_eq!(workers(Some(1)).unwrap().pool.current_num_threads(), 1);
        let cpus = std::thread::available_parallelism().unwrap().get();
        let w = workers(Some(cpus + 5)).unwrap();
        assert_eq!(w.capped, Some((cpus + 5, cpus)));
        assert_eq!(w.pool.current_num_threads(), cpus);
    }
}
