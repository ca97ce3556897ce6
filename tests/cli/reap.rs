//! A child process that cannot outlive its test: dropped, it is killed if still running and
//! reaped, so a test that fails between starting `t2tf` and waiting for it leaves no run
//! behind (a 100000-step `optimize` would go on long after the test binary ended).

#![allow(dead_code)] // each test file uses what it needs

use std::ops::{Deref, DerefMut};
use std::process::{Child, Command, Output};

/// A running child, killed and reaped on drop.
pub struct Reaped(Option<Child>);

impl Reaped {
    /// Start `cmd`.
    pub fn spawn(cmd: &mut Command) -> Reaped {
        Reaped(Some(cmd.spawn().expect("start the child")))
    }

    /// Wait for the child and collect what it wrote to piped stdout and stderr.
    pub fn wait_with_output(mut self) -> std::io::Result<Output> {
        self.0.take().expect("the child").wait_with_output()
    }
}

impl Deref for Reaped {
    type Target = Child;

    fn deref(&self) -> &Child {
        self.0.as_ref().expect("the child")
    }
}

impl DerefMut for Reaped {
    fn deref_mut(&mut self) -> &mut Child {
        self.0.as_mut().expect("the child")
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Some(mut child) = self.0.take() {
            if !matches!(child.try_wait(), Ok(Some(_))) {
                let _ = child.kill();
            }
            let _ = child.wait();
        }
    }
}
