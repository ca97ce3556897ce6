//! Windows: `sysinfo` for processes, `windows-sys` for the few flags std leaves to us.

use std::fs::OpenOptions;
use std::os::windows::fs::OpenOptionsExt;

/// Windows has no address-space limit of the `ulimit -v` kind: `None`.
pub fn address_space_left() -> Option<u64> {
    None
}

/// The system's page size.
pub fn page_size() -> usize {
    use windows_sys::Win32::System::SystemInformation::{GetSystemInfo, SYSTEM_INFO};
    // SAFETY: GetSystemInfo fills the struct it is given; a zeroed SYSTEM_INFO is valid.
    let info = unsafe {
        let mut info: SYSTEM_INFO = std::mem::zeroed();
        GetSystemInfo(&mut info);
        info
    };
    match info.dwPageSize {
        0 => 4096,
        p => p as usize,
    }
}

/// Whether process `pid` still runs (from the system's process table).
pub fn process_alive(pid: u32) -> bool {
    use sysinfo::{Pid, ProcessRefreshKind, ProcessesToUpdate, System};
    let pid = Pid::from_u32(pid);
    let mut sys = System::new();
    sys.refresh_processes_specifics(
        ProcessesToUpdate::Some(&[pid]),
        true,
        ProcessRefreshKind::nothing(),
    );
    sys.process(pid).is_some()
}

/// Open the name itself: a symlink or junction there is opened as the reparse point, not
/// followed (`FILE_FLAG_OPEN_REPARSE_POINT`); the caller then sees it is not a regular file.
pub fn no_follow(options: &mut OpenOptions) -> &mut OpenOptions {
    use windows_sys::Win32::Storage::FileSystem::FILE_FLAG_OPEN_REPARSE_POINT;
    options.custom_flags(FILE_FLAG_OPEN_REPARSE_POINT)
}

/// As `no_follow`: opening a file never waits on Windows (named pipes live outside the file
/// system's folders).
pub fn no_follow_no_wait(options: &mut OpenOptions) -> &mut OpenOptions {
    no_follow(options)
}

/// Making a symlink on Windows takes a privilege (or developer mode) an attacker's account
/// lacks, so a symlink the caller can reach counts as the caller's (owner shown as 0).
pub fn link_owned_by_caller(_meta: &std::fs::Metadata) -> (bool, u32) {
    (true, 0)
}

/// Windows trims a file mapping's pages from the working set itself: nothing to do.
pub fn release_pages(_map: &memmap2::Mmap, _range: std::ops::Range<usize>) {}

/// Whether `path` names the open `file`: same volume and file index (`same-file`). A
/// reparse point at `path` is not the file, nor is a file being deleted (Windows keeps a
/// removed file's name until its last handle closes, where deletes are not POSIX-style).
pub fn same_file(file: &std::fs::File, path: &std::path::Path) -> bool {
    if delete_pending(file) {
        return false;
    }
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    if is_link {
        return false;
    }
    let ours = file.try_clone().map(same_file::Handle::from_file);
    match (ours, same_file::Handle::from_path(path)) {
        (Ok(Ok(a)), Ok(b)) => a == b,
        _ => false,
    }
}

/// How many names the open file has (`nNumberOfLinks`).
pub fn hard_links(file: &std::fs::File, _meta: &std::fs::Metadata) -> u64 {
    use std::os::windows::io::AsRawHandle;
    use windows_sys::Win32::Storage::FileSystem::{
        GetFileInformationByHandle, BY_HANDLE_FILE_INFORMATION,
    };
    // SAFETY: the handle is open for as long as `file` is borrowed; the struct is written by
    // the call (a zeroed one is valid).
    unsafe {
        let mut info: BY_HANDLE_FILE_INFORMATION = std::mem::zeroed();
        if GetFileInformationByHandle(file.as_raw_handle(), &mut info) == 0 {
            return 1;
        }
        u64::from(info.nNumberOfLinks)
    }
}

/// Open `path` for reading: opening a file never waits on Windows. With
/// `FILE_FLAG_BACKUP_SEMANTICS` a folder opens too (else "Access denied"), so the caller can
/// say that it is a folder.
pub fn open_without_waiting(path: &std::path::Path) -> std::io::Result<std::fs::File> {
    use windows_sys::Win32::Storage::FileSystem::FILE_FLAG_BACKUP_SEMANTICS;
    OpenOptions::new()
        .read(true)
        .custom_flags(FILE_FLAG_BACKUP_SEMANTICS)
        .open(path)
}

/// Nothing to clear on Windows.
pub fn set_blocking(_file: &std::fs::File) -> std::io::Result<()> {
    Ok(())
}

/// Windows' heap returns large freed blocks to the system itself: nothing to do.
pub fn return_freed_memory() {}

/// Whether the open `file` was removed (its name waits for the last handle to close).
fn delete_pending(file: &std::fs::File) -> bool {
    use std::os::windows::io::AsRawHandle;
    use windows_sys::Win32::Storage::FileSystem::{
        FileStandardInfo, GetFileInformationByHandleEx, FILE_STANDARD_INFO,
    };
    // SAFETY: the handle is open while `file` is borrowed; the call writes at most the
    // struct's size into it (a zeroed FILE_STANDARD_INFO is valid).
    unsafe {
        let mut info: FILE_STANDARD_INFO = std::mem::zeroed();
        let ok = GetFileInformationByHandleEx(
            file.as_raw_handle(),
            FileStandardInfo,
            (&mut info as *mut FILE_STANDARD_INFO).cast(),
            std::mem::size_of::<FILE_STANDARD_INFO>() as u32,
        );
        ok != 0 && info.DeletePending
    }
}
