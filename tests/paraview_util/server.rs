//! A ParaView server for the client-server tests: `mpiexec -n N pvserver` on 127.0.0.1 under
//! its own virtual X server, stopped (with all its processes) when the guard is dropped,
//! whether the test passed, failed or panicked.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// `mpiexec` and `pvserver` are here, or the test fails naming what is missing (on Debian,
/// `mpiexec` comes from the openmpi-bin package). Tests calling this are ignored where the
/// build found no pvserver (`cfg(t2tf_pvserver)`).
pub fn require_pvserver(test: &str) {
    super::require_tools(test, &["mpiexec", "pvserver"]);
}

/// A running `xvfb-run -a mpiexec -n N pvserver --server-port=PORT`; dropping it stops the
/// whole process group (xvfb-run, Xvfb, mpiexec and every pvserver rank).
pub struct PvServer {
    child: Child,
    /// The port the server accepts its one client on.
    pub port: u16,
    log: PathBuf,
}

impl PvServer {
    /// Start `ranks` pvserver processes and wait until they accept a connection (at most
    /// 120 s). Errors carry the server's output.
    pub fn start(ranks: usize, dir: &Path) -> Result<PvServer, String> {
        use std::os::unix::process::CommandExt;

        // A port that was free a moment ago (the OS picks it); pvserver binds it next.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(|e| format!("no free port: {e}"))?
            .port();
        let log = dir.join(format!("pvserver-{port}.log"));
        let file = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
        let err = file.try_clone().map_err(|e| e.to_string())?;
        let child = Command::new("xvfb-run")
            .args(super::xvfb_display_args())
            .args(["mpiexec", "-n", &ranks.to_string(), "pvserver"])
            .arg(format!("--server-port={port}"))
            // Python plugins (t2tf_plugin.py loaded with remote=True) need ParaView 5.11's
            // compat path on the server too (paraview/README.md).
            .env("PYTHONPATH", super::repo().join("paraview/compat"))
            // Open MPI refuses to start as root (containers, CI) without both of these.
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .stdin(Stdio::null())
            .stdout(file)
            .stderr(err)
            // Its own process group, so that Drop can stop every process it started.
            .process_group(0)
            .spawn()
            .map_err(|e| format!("could not start xvfb-run mpiexec pvserver: {e}"))?;
        let mut server = PvServer { child, port, log };
        let start = Instant::now();
        loop {
            let text = server.log_text();
            if text.contains("Accepting connection") {
                return Ok(server);
            }
            if let Ok(Some(status)) = server.child.try_wait() {
                return Err(format!(
                    "pvserver exited ({status}) before accepting:\n{text}"
                ));
            }
            if start.elapsed() > Duration::from_secs(120) {
                return Err(format!("pvserver did not accept within 120 s:\n{text}"));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// What the server printed so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for PvServer {
    fn drop(&mut self) {
        let group = self.child.id() as libc::pid_t;
        // SIGTERM first (xvfb-run then stops its Xvfb, mpiexec its ranks), SIGKILL after 5 s.
        // SAFETY: kill(2) with a negative pid signals our own child's process group only.
        unsafe { libc::kill(-group, libc::SIGTERM) };
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        // The group may outlive its leader (orphaned ranks): kill what is left of it.
        unsafe { libc::kill(-group, libc::SIGKILL) };
        let _ = self.child.wait();
    }
}
