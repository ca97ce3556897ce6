//! What differs between operating systems, in one place: every other module of t2tf asks
//! here instead of calling the system itself. Linux, macOS and the other Unixes share
//! `unix.rs`; Windows has `windows.rs`; what a well-kept crate answers the same way on every
//! system (memory, processes, the CPU's name: `sysinfo`; the user's folders: `directories`)
//! is answered here directly. macOS asks its kernel itself (`macos.rs`): `sysinfo` links
//! Apple frameworks that a build from Linux has no SDK for.
//!
//! | question | Unix | Windows |
//! |---|---|---|
//! | memory the system can give | Linux: `sysinfo` (MemAvailable); macOS: `host_statistics64` (`macos.rs`); capped by `ulimit -v` | `sysinfo` (available physical memory) |
//! | does process PID run | `kill(pid, 0)` | `sysinfo`'s process table |
//! | open a name, not what it links to | `O_NOFOLLOW` | `FILE_FLAG_OPEN_REPARSE_POINT` |
//! | who owns a symlink | its uid against the effective uid | symlinks need a privilege to make: the caller's |
//! | is this name that open file | device and inode | volume and file index (`same-file`) |
//! | lock a file | `flock` (std's `File::try_lock`) | `LockFileEx` (the same call) |
//! | give freed heap memory back | `malloc_trim` (glibc) | nothing (the heap does) |
//! | stop counting a mapped file's pages | `madvise(MADV_DONTNEED)` | nothing (Windows trims a mapping's pages itself) |
//! | may this process use AMX tiles | CPUID, XCR0, then Linux: `arch_prctl(ARCH_REQ_XCOMP_PERM)` | CPUID and XCR0 |
//! | the CPU's name and flags | `/proc/cpuinfo` on Linux, else `sysinfo` and the CPU's own feature bits | `sysinfo` and the CPU's own feature bits |

use std::path::PathBuf;

#[cfg(unix)]
mod unix;
#[cfg(unix)]
use unix as os;
#[cfg(windows)]
mod windows;
#[cfg(windows)]
use windows as os;

pub use os::{
    address_space_left, hard_links, link_owned_by_caller, no_follow, no_follow_no_wait,
    open_without_waiting, page_size, process_alive, release_pages, return_freed_memory, same_file,
    set_blocking,
};

#[cfg(target_vendor = "apple")]
mod macos;

mod cpu;
pub use cpu::{amx_tiles, cpu, has_flag, Cpu};

/// Physical memory the system can give this process now, in bytes (`None`: unknown).
#[cfg(target_vendor = "apple")]
pub fn available_memory() -> Option<u64> {
    macos::available_memory()
}

/// Physical memory the system can give this process now, in bytes (`None`: unknown).
#[cfg(not(target_vendor = "apple"))]
pub fn available_memory() -> Option<u64> {
    use sysinfo::{MemoryRefreshKind, RefreshKind, System};
    let sys = System::new_with_specifics(
        RefreshKind::nothing().with_memory(MemoryRefreshKind::nothing().with_ram()),
    );
    match sys.available_memory() {
        0 => None,
        bytes => Some(bytes),
    }
}

/// `path` made absolute with links and `..` resolved (`std::fs::canonicalize`), on Windows
/// as a drive-letter or UNC path (`C:\data\head.vti`) where one names it, not the
/// `\\?\C:\…` form std returns, which many programs (ParaView's readers, VisIt) do not
/// open (`dunce`).
pub fn canonicalize(path: &std::path::Path) -> std::io::Result<PathBuf> {
    dunce::canonicalize(path)
}

/// The folder for t2tf's own cached data where the platform keeps per-user caches:
/// `$XDG_CACHE_HOME/t2tf` or `~/.cache/t2tf` on Linux, `~/Library/Caches/t2tf` on macOS,
/// `%LOCALAPPDATA%\t2tf\cache` on Windows. `None` when the system names no home folder.
pub fn cache_dir() -> Option<PathBuf> {
    directories::ProjectDirs::from("", "", "t2tf").map(|d| d.cache_dir().to_path_buf())
}

/// The user's home folder (`$HOME` on Unix, the profile folder on Windows), as Python's
/// `os.path.expanduser("~")` finds it there.
pub fn home_dir() -> Option<PathBuf> {
    directories::BaseDirs::new().map(|d| d.home_dir().to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_runs_and_a_finished_child_does_not() {
        assert!(process_alive(std::process::id()));
        let exe = std::env::current_exe().unwrap();
        let mut child = std::process::Command::new(exe)
            .arg("--list")
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let pid = child.id();
        child.wait().unwrap();
        assert!(
            !process_alive(pid),
            "process {pid} was reaped but counts as running"
        );
    }

    #[test]
    fn the_system_reports_some_memory_and_a_page_size() {
        let mem = available_memory().expect("the system says how much memory is available");
        assert!(mem > 1 << 20, "{mem} bytes");
        let page = page_size();
        assert!(page.is_power_of_two() && page >= 4096, "page size {page}");
    }

    #[test]
    fn canonical_paths_are_absolute_and_in_the_form_other_programs_open() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("a b")).unwrap();
        std::fs::write(dir.path().join("f.raw"), b"x").unwrap();
        let messy = dir.path().join("a b").join("..").join("f.raw");
        let clean = canonicalize(&messy).unwrap();
        assert!(clean.is_absolute(), "{}", clean.display());
        assert!(
            !clean.to_string_lossy().starts_with(r"\\?\"),
            "{}",
            clean.display()
        );
        assert!(
            !clean.to_string_lossy().contains(".."),
            "{}",
            clean.display()
        );
        assert_eq!(std::fs::read(&clean).unwrap(), b"x");
    }

    #[test]
    fn the_cache_folder_is_under_the_home_folder_or_the_platforms_cache() {
        let cache = cache_dir().expect("a cache folder");
        assert!(cache.is_absolute(), "{}", cache.display());
        assert!(cache.to_string_lossy().to_lowercase().contains("t2tf"));
    }
}
