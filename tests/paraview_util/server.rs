//! A ParaView server for the client-server tests: `mpiexec -n N pvserver` on 127.0.0.1 under
//! its own virtual X server, stopped (with all its processes) when the guard is dropped,
//! whether the test passed, failed or panicked.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// `mpiexec`, `pvserver` and `Xvfb` are here, or the test fails naming what is missing (on Debian,
/// `mpiexec` comes from the openmpi-bin package). Tests calling this are ignored where the
/// build found no pvserver (`cfg(t2tf_pvserver)`).
pub fn require_pvserver(test: &str) {
    super::require_tools(test, &["mpiexec", "pvserver", "Xvfb"]);
}

/// A running `mpiexec -n N pvserver --server-port=PORT` on its own Xvfb; dropping it stops both
/// process groups (Xvfb; mpiexec and every pvserver rank).
///
/// The harness avoids the moving parts that can differ between the machines it meets: Xvfb
/// picks a free display itself (`-displayfd`, race-free against other X servers) and runs
/// without an authority file (`-ac`: only local clients, no cookie to lose), and the ranks talk
/// over loopback TCP (`btl self,tcp`) rather than Open MPI's shared-memory transport, whose
/// single-copy reads between sibling processes a sandbox may forbid.
pub struct PvServer {
    // Dropped in this order: the ranks first (they hold connections to the X server), then
    // Xvfb.
    mpiexec: GroupLeader,
    xvfb: GroupLeader,
    /// The port the server accepts its one client on.
    pub port: u16,
    log: PathBuf,
}

impl PvServer {
    /// Start `ranks` pvserver processes and wait until they accept a connection (at most
    /// 120 s). Errors carry the server's output.
    pub fn start(ranks: usize, dir: &Path) -> Result<PvServer, String> {
        use std::io::BufRead;
        use std::os::unix::process::CommandExt;

        let log = dir.join("pvserver.log");
        let file = std::fs::File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
        let clone = || file.try_clone().map_err(|e| e.to_string());
        // Stopped with its group when `xvfb` drops: on every early return below too.
        let mut xvfb = GroupLeader(
            Command::new("Xvfb")
                .args(["-displayfd", "1", "-ac", "-nolisten", "tcp"])
                .args(["-screen", "0", "1280x1024x24"])
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(clone()?)
                .process_group(0)
                .spawn()
                .map_err(|e| format!("could not start Xvfb: {e}"))?,
        );
        // Xvfb writes its display number once it accepts connections, or exits.
        let mut display = String::new();
        let read =
            std::io::BufReader::new(xvfb.0.stdout.take().expect("piped")).read_line(&mut display);
        let display = display.trim().to_string();
        if read.is_err() || display.parse::<u32>().is_err() {
            drop(xvfb);
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            return Err(format!("Xvfb did not start:\n{text}"));
        }

        // A port that was free a moment ago (the OS picks it); pvserver binds it next.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(|e| format!("no free port: {e}"))?
            .port();
        let mpiexec = Command::new("mpiexec")
            .args(["--oversubscribe", "-n", &ranks.to_string(), "pvserver"])
            .arg(format!("--server-port={port}"))
            .env("DISPLAY", format!(":{display}"))
            .env_remove("XAUTHORITY")
            .env("OMPI_MCA_btl", "self,tcp")
            .env("OMPI_MCA_btl_tcp_if_include", "lo")
            // Python plugins (t2tf_plugin.py loaded with remote=True) need ParaView 5.11's
            // compat path on the server too (paraview/README.md).
            .env("PYTHONPATH", super::repo().join("paraview/compat"))
            // Open MPI refuses to start as root (containers, CI) without both of these.
            .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
            .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
            .stdin(Stdio::null())
            .stdout(clone()?)
            .stderr(clone()?)
            // Its own process group, so that Drop can stop every process it started.
            .process_group(0)
            .spawn();
        let mpiexec = match mpiexec {
            Ok(child) => GroupLeader(child),
            Err(e) => return Err(format!("could not start mpiexec pvserver: {e}")),
        };
        let mut server = PvServer {
            mpiexec,
            xvfb,
            port,
            log,
        };
        let start = Instant::now();
        loop {
            let text = server.log_text();
            if text.contains("Accepting connection") {
                return Ok(server);
            }
            if let Ok(Some(status)) = server.mpiexec.0.try_wait() {
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

    /// What the server (Xvfb, mpiexec, the ranks) printed so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

/// A child that leads its own process group; dropped, the group is stopped (SIGTERM, SIGKILL
/// to what is left after 5 s), the leader reaped, and any member that outlived it (an
/// orphaned rank) stopped too, whether the test passed, failed or panicked.
struct GroupLeader(Child);

impl Drop for GroupLeader {
    fn drop(&mut self) {
        let child = &mut self.0;
        let group = child.id() as libc::pid_t;
        // SAFETY: kill(2) with a negative pid signals the process group of our own child,
        // which is not reaped yet, so the group's number is still its.
        unsafe { libc::kill(-group, libc::SIGTERM) };
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        if let Ok(None) = child.try_wait() {
            // SAFETY: as above; the leader still runs.
            unsafe { libc::kill(-group, libc::SIGKILL) };
        }
        let _ = child.wait();
        // The group may outlive its leader (orphaned ranks).
        super::stop_group(group);
    }
}
