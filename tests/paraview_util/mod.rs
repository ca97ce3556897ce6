//! What the ParaView integration tests share: finding pvpython, running it one at a time
//! under xvfb, and comparing images.

#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};
use std::process::Command;

use t2tf::image::Image;
use t2tf::tf::ControlPoints;

pub mod server;

/// pvpython and xvfb-run are here, or the test fails naming what is missing. A test that calls
/// this is ignored where the build found no ParaView (`cfg(t2tf_pvpython)`, build.rs), so it
/// runs only where they are, or where T2TF_REQUIRE_PARAVIEW says they must be.
pub fn require_paraview(test: &str) {
    require_tools(test, &["pvpython", "xvfb-run"]);
}

/// Every program in `exes` is on PATH, or the test fails naming the missing ones.
pub fn require_tools(test: &str, exes: &[&str]) {
    let missing: Vec<&str> = exes
        .iter()
        .copied()
        .filter(|exe| {
            !Command::new("sh")
                .args(["-c", &format!("command -v {exe}")])
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .collect();
    assert!(
        missing.is_empty(),
        "{test}: {} not found on PATH (build.rs found them, or T2TF_REQUIRE_PARAVIEW requires them)",
        missing.join(" and ")
    );
}

/// One pvpython at a time: `xvfb-run -a` picks a free display number by probing, and two
/// starting at once can pick the same one ("bad X server connection", SIGABRT).
pub static PVPYTHON: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Run `xvfb-run -a pvpython --dr SCRIPT ARGS...`, panicking with its output on failure.
pub fn pvpython(script: &Path, args: &[&str]) -> String {
    let out = pvpython_output(script, args);
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    if !out.status.success() {
        panic!("pvpython {} failed:\n{text}", script.display());
    }
    text
}

/// Run `xvfb-run -a pvpython --dr SCRIPT ARGS...` and return what it did, success or not.
pub fn pvpython_output(script: &Path, args: &[&str]) -> std::process::Output {
    let _one = PVPYTHON.lock().unwrap_or_else(|e| e.into_inner());
    xvfb_pvpython(script, |c| {
        c.args(args);
    })
}

/// `xvfb-run`'s arguments for a free display: `-a` searches upward for one, starting from a
/// number drawn per call (`-n`). From the default 99 every `xvfb-run -a` on the machine probes
/// the same numbers, and two starting together can take the same one: the loser's client then
/// meets the winner's server with the wrong cookie ("bad X server connection").
pub fn xvfb_display_args() -> [String; 3] {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    let n = 200 + h.finish() % 30_000;
    ["-a".into(), "-n".into(), n.to_string()]
}

/// Run `timeout 300 xvfb-run -a pvpython --dr SCRIPT` with what `configure` adds (arguments,
/// environment). The caller holds [`PVPYTHON`]. A failure to reach the X server is retried:
/// an X server that another `xvfb-run` on this machine just stopped, or just started on the
/// same display number, shows as "bad X server connection" and a SIGABRT in pvpython before
/// the script runs a line.
pub fn xvfb_pvpython(script: &Path, configure: impl Fn(&mut Command)) -> std::process::Output {
    let mut attempt = 0;
    loop {
        attempt += 1;
        let mut command = Command::new("timeout");
        command
            .args(["300", "xvfb-run"])
            .args(xvfb_display_args())
            .args(["pvpython", "--dr"])
            .arg(script);
        configure(&mut command);
        let out = output_in_group(&mut command).expect("run timeout xvfb-run pvpython");
        if attempt < 5 && lost_display(&out, "") {
            eprintln!("pvpython could not reach Xvfb (attempt {attempt}); retrying");
            std::thread::sleep(std::time::Duration::from_millis(500 * attempt));
            continue;
        }
        return out;
    }
}

/// Run `command` (`timeout 300 xvfb-run …`) in a process group of its own and collect its
/// output; then stop whatever is left in that group, the command passed or not. `xvfb-run`
/// stops its Xvfb only when it exits normally, and a program ParaView started (a `t2tf` run
/// of the plugin) may outlive pvpython: anything in the group after the command returns
/// (or if the test binary dies meanwhile: `timeout` gets SIGTERM, which it passes on to the
/// group) does not outlive the test.
pub fn output_in_group(command: &mut Command) -> std::io::Result<std::process::Output> {
    use std::process::Stdio;
    // What `Command::output` does: no input, both outputs captured.
    command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let (child, _group) = spawn_in_group(command)?;
    child.wait_with_output()
}

/// Start `command` as the leader of a new process group, with the guard that stops what is
/// left of the group when dropped (see [`output_in_group`]).
pub fn spawn_in_group(command: &mut Command) -> std::io::Result<(std::process::Child, Group)> {
    use std::os::unix::process::CommandExt;
    command.process_group(0);
    #[cfg(target_os = "linux")]
    // SAFETY: prctl is async-signal-safe; it only sets this child's parent-death signal.
    unsafe {
        command.pre_exec(|| {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    let child = command.spawn()?;
    let group = Group(child.id() as libc::pid_t);
    Ok((child, group))
}

/// A process group a test started (its leader's pid): dropped, whatever is still in it is
/// stopped (SIGTERM, then SIGKILL after 5 s), even when the test panics.
pub struct Group(pub libc::pid_t);

impl Drop for Group {
    fn drop(&mut self) {
        stop_group(self.0);
    }
}

/// Whether any process is still in process group `group` (the fifth field of
/// `/proc/PID/stat`). A group's number is not given to a new process while a member lives,
/// so signalling the group after this says yes reaches only what the test started.
pub fn group_alive(group: libc::pid_t) -> bool {
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return false;
    };
    entries.flatten().any(|e| {
        let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
        // After the command name in parentheses: state, ppid, pgrp. A zombie has ended (its
        // parent reaps it).
        let fields: Vec<&str> = stat
            .rsplit_once(") ")
            .map_or(Vec::new(), |(_, rest)| rest.split(' ').take(3).collect());
        fields.len() == 3 && fields[0] != "Z" && fields[2].parse() == Ok(group)
    })
}

/// SIGTERM to what is left of process group `group`, SIGKILL to what still is after 5 s.
pub fn stop_group(group: libc::pid_t) {
    use std::time::{Duration, Instant};
    if group <= 1 || !group_alive(group) {
        return;
    }
    // SAFETY: kill(2) with a negative pid signals that process group only: one this test
    // started and whose members are alive (checked above).
    unsafe { libc::kill(-group, libc::SIGTERM) };
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(5) {
        if !group_alive(group) {
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    unsafe { libc::kill(-group, libc::SIGKILL) };
}

/// Whether a failed run (with `extra` log text, e.g. a server's) lost its X display.
pub fn lost_display(out: &std::process::Output, extra: &str) -> bool {
    !out.status.success()
        && format!("{}{extra}", String::from_utf8_lossy(&out.stderr))
            .contains("bad X server connection")
}

/// `text` with each distinct line once, in order: a ParaView process that lost its peer repeats
/// one socket error hundreds of times, and a failing test's message should show the rest.
pub fn distinct_lines(text: &str) -> String {
    let mut seen = std::collections::HashSet::new();
    let mut out = String::new();
    for line in text.lines() {
        // VTK prefixes each message with the seconds since start, "(   3.566s) " (after colour
        // codes): compare what follows it.
        let key = match line.find("s) ") {
            Some(i) if i < 32 && line[..i].contains('(') => &line[i + 3..],
            _ => line,
        };
        if seen.insert(key) {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// The TF the preset and script tests export: five points from transparent blue to opaque
/// white.
pub fn test_tf() -> ControlPoints {
    ControlPoints {
        x: vec![0.0, 0.2, 0.45, 0.7, 1.0],
        sigma: vec![0.0, 5.0, 60.0, 180.0, 255.0],
        rgb: vec![
            [0.1, 0.1, 0.8],
            [0.2, 0.6, 0.9],
            [0.9, 0.8, 0.2],
            [1.0, 0.3, 0.1],
            [1.0, 1.0, 1.0],
        ],
    }
}

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shared 64³ neghip volume (../shared/data/volumes).
pub fn neghip_path() -> PathBuf {
    repo().join("../shared/data/volumes/neghip_64x64x64_uint8.raw")
}

/// The neghip volume, loaded as the CLI loads it (`Volume::source` set).
pub fn neghip() -> t2tf::volume::Volume {
    let path = neghip_path();
    t2tf::volume::load(&path, &Default::default())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

pub fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

/// Assert that `img` differs from the background colour `bg` nowhere outside the projected
/// box `b` = (x0, y0, x1, y1) and in more than 30 % of the pixels inside it. A 2-pixel margin
/// absorbs rasterization at the silhouette.
pub fn assert_volume_only_inside(img: &Image, b: [f64; 4], bg: [f64; 3]) {
    let is_bg = |p: [f32; 3]| (0..3).all(|i| (p[i] as f64 - bg[i]).abs() <= 1.5 / 255.0);
    let (mut inside, mut inside_differs, mut outside_differs) = (0, 0, 0);
    for y in 0..img.height {
        for x in 0..img.width {
            let (cx, cy) = (x as f64 + 0.5, y as f64 + 0.5);
            let differs = !is_bg(img.pixel(x, y));
            if cx < b[0] - 2.0 || cx > b[2] + 2.0 || cy < b[1] - 2.0 || cy > b[3] + 2.0 {
                outside_differs += differs as usize;
            } else if cx > b[0] + 2.0 && cx < b[2] - 2.0 && cy > b[1] + 2.0 && cy < b[3] - 2.0 {
                inside += 1;
                inside_differs += differs as usize;
            }
        }
    }
    assert_eq!(
        outside_differs, 0,
        "pixels outside the projected box {b:?} changed"
    );
    let frac = inside_differs as f64 / inside as f64;
    eprintln!("projected box {b:?}: {inside_differs}/{inside} inside pixels show the volume");
    assert!(frac > 0.3, "only {frac} of the box shows the volume");
}

/// Pixel rectangle (x0, y0, x1, y1) covering the volume's box as seen by `cam` (a pinhole with
/// a vertical view angle, as ParaView's and ours) in a `w`×`h` image.
pub fn projected_box(
    v: &t2tf::volume::Volume,
    cam: &t2tf::camera::ParaViewCamera,
    w: usize,
    h: usize,
) -> [f64; 4] {
    use glam::DVec3;
    let (pos, focal, up) = (
        DVec3::from(cam.position),
        DVec3::from(cam.focal_point),
        DVec3::from(cam.view_up),
    );
    let f = (focal - pos).normalize();
    let r = f.cross(up).normalize();
    let u = r.cross(f);
    let t = (cam.view_angle.to_radians() / 2.0).tan();
    let aspect = w as f64 / h as f64;
    let (o, e) = (v.geometry.origin, v.geometry.extent());
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for c in 0..8 {
        let corner: [f64; 3] = std::array::from_fn(|a| o[a] + e[a] * ((c >> a) & 1) as f64);
        let d = DVec3::from(corner) - pos;
        let z = d.dot(f);
        let px = (d.dot(r) / (z * t * aspect) + 1.0) / 2.0 * w as f64;
        let py = (1.0 - d.dot(u) / (z * t)) / 2.0 * h as f64;
        b = [b[0].min(px), b[1].min(py), b[2].max(px), b[3].max(py)];
    }
    b
}
