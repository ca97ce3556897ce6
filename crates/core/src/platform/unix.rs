//! Unix (Linux, macOS, the BSDs): `libc` calls.

use std::fs::OpenOptions;
use std::os::unix::fs::OpenOptionsExt;

/// Room left under the address-space limit (`ulimit -v`), `None` where there is no limit.
pub fn address_space_left() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } != 0 {
        return None;
    }
    if lim.rlim_cur == libc::RLIM_INFINITY {
        return None;
    }
    // rlim_t is u64 on Linux but not on every Unix.
    #[allow(clippy::useless_conversion)]
    let limit = u64::try_from(lim.rlim_cur).ok()?;
    Some(limit.saturating_sub(mapped_now().unwrap_or(0)))
}

/// Virtual memory mapped by this process (what RLIMIT_AS counts); Linux says in
/// `/proc/self/statm`, other Unixes give `None` (and the limit counts in full).
fn mapped_now() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().next()?.parse().ok()?;
    pages.checked_mul(page_size() as u64)
}

/// The system's page size (4 KiB on x86-64, 16 KiB on Apple silicon, 64 KiB on some ARM
/// Linux kernels).
pub fn page_size() -> usize {
    // SAFETY: sysconf only reads a system constant.
    match unsafe { libc::sysconf(libc::_SC_PAGESIZE) } {
        p if p > 0 => p as usize,
        _ => 4096,
    }
}

/// Whether process `pid` still runs (a PID that is not ours to signal counts as running).
pub fn process_alive(pid: u32) -> bool {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: kill with signal 0 only checks that the process exists; it sends nothing.
    let r = unsafe { libc::kill(pid, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Open the name itself: a symlink there makes the open fail (`O_NOFOLLOW`); new files get
/// mode 0644 before the umask (outputs are ordinary user files).
pub fn no_follow(options: &mut OpenOptions) -> &mut OpenOptions {
    options.mode(0o644).custom_flags(libc::O_NOFOLLOW)
}

/// `no_follow`, and open without waiting (`O_NONBLOCK`): a FIFO without a writer cannot hang
/// the open.
pub fn no_follow_no_wait(options: &mut OpenOptions) -> &mut OpenOptions {
    options.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
}

/// Whether the symlink described by `meta` belongs to the caller (the effective uid), and
/// its owner's uid for messages.
pub fn link_owned_by_caller(meta: &std::fs::Metadata) -> (bool, u32) {
    use std::os::unix::fs::MetadataExt;
    // SAFETY: geteuid has no preconditions and cannot fail.
    let me = unsafe { libc::geteuid() };
    (meta.uid() == me, meta.uid())
}

/// Stop counting the pages of `map` in `range` (whole pages, `page_size` aligned) as this
/// process's memory (`MADV_DONTNEED`). For a read-only shared file mapping only: its pages
/// read back from the file unchanged, so no reference sees other bytes. A failure only means
/// the pages stay counted.
pub fn release_pages(map: &memmap2::Mmap, range: std::ops::Range<usize>) {
    if range.end > range.start {
        // SAFETY: as documented: the pages of a read-only file mapping read back unchanged.
        let _ = unsafe {
            map.unchecked_advise_range(
                memmap2::UncheckedAdvice::DontNeed,
                range.start,
                range.end - range.start,
            )
        };
    }
}

/// Whether `path` (not followed) names the open `file`: same device and inode.
pub fn same_file(file: &std::fs::File, path: &std::path::Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::symlink_metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// How many names the open file has (`st_nlink`).
pub fn hard_links(_file: &std::fs::File, meta: &std::fs::Metadata) -> u64 {
    use std::os::unix::fs::MetadataExt;
    meta.nlink()
}

/// Open `path` for reading (links followed) without waiting: a FIFO without a writer cannot
/// hang the open (`O_NONBLOCK`; [`set_blocking`] clears it once the file is known regular).
pub fn open_without_waiting(path: &std::path::Path) -> std::io::Result<std::fs::File> {
    OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
}

/// Make reads of `file` wait again (clear `O_NONBLOCK`).
pub fn set_blocking(file: &std::fs::File) -> std::io::Result<()> {
    use std::os::unix::io::AsRawFd;
    let fd = file.as_raw_fd();
    // SAFETY: fcntl on a descriptor the caller owns, with integer arguments.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Hand the memory this process has freed back to the system, after dropping something
/// large (a model tower, a load's buffers). glibc's malloc keeps freed blocks of up to 32 MiB
/// in its arenas once a block that size was freed (its mmap threshold adapts), and those
/// pages stay counted as the process's memory: without this a dropped text tower would
/// still count in a run's peak. Elsewhere (other C libraries) a no-op.
pub fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Ask Linux for the AMX tile data (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`):
/// the kernel enables it per process, on request. Asking twice is harmless.
#[cfg(all(target_os = "linux", target_arch = "x86_64"))]
pub(super) fn request_tile_data() -> Result<(), String> {
    /// `ARCH_REQ_XCOMP_PERM` and `XFEATURE_XTILEDATA` (arch/x86/include/uapi/asm/prctl.h and
    /// the XSAVE feature number of the tile data), which the libc crate does not name.
    const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_long = 18;
    // SAFETY: arch_prctl with these arguments only changes this process's permitted
    // extended-state components; it reads and writes no memory of ours.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "Linux refused the AMX tile data ({}; Linux 5.16 or later is needed)",
            std::io::Error::last_os_error()
        ))
    }
}
