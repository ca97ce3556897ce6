//! macOS: available memory and the CPU's name from the kernel (`host_statistics64`,
//! `sysctlbyname`) through `libc`. `sysinfo` would link Apple's IOKit and CoreFoundation
//! frameworks, which a build from Linux (cargo-zigbuild) has no SDK for; these two calls are
//! all t2tf asks of it.

/// Free, inactive, purgeable and speculative pages: what the kernel can hand out without
/// swapping (Activity Monitor's free plus cached).
pub fn available_memory() -> Option<u64> {
    let mut stats: libc::vm_statistics64 = unsafe_zeroed();
    let mut count = libc::HOST_VM_INFO64_COUNT;
    // SAFETY: host_statistics64 writes at most `count` integers into `stats`, which is that
    // large; mach_host_self has no preconditions. (libc marks mach_host_self deprecated in
    // favour of the mach2 crate; the system call is the same.)
    #[allow(deprecated)]
    let r = unsafe {
        libc::host_statistics64(
            libc::mach_host_self(),
            libc::HOST_VM_INFO64,
            (&mut stats as *mut libc::vm_statistics64).cast(),
            &mut count,
        )
    };
    if r != libc::KERN_SUCCESS {
        return None;
    }
    let pages = u64::from(stats.free_count)
        + u64::from(stats.inactive_count)
        + u64::from(stats.purgeable_count)
        + u64::from(stats.speculative_count);
    pages.checked_mul(super::page_size() as u64)
}

/// `machdep.cpu.brand_string` ("Apple M2", "Intel(R) Core(TM) i9-9880H …").
pub fn cpu_brand() -> Option<String> {
    let mut buf = [0u8; 256];
    let mut len = buf.len();
    // SAFETY: sysctlbyname writes at most `len` bytes into `buf` and the length back into
    // `len`; the name is a NUL-terminated literal.
    let r = unsafe {
        libc::sysctlbyname(
            c"machdep.cpu.brand_string".as_ptr(),
            buf.as_mut_ptr().cast(),
            &mut len,
            std::ptr::null_mut(),
            0,
        )
    };
    if r != 0 {
        return None;
    }
    let text = &buf[..len.min(buf.len())];
    let end = text.iter().position(|&b| b == 0).unwrap_or(text.len());
    let brand = String::from_utf8_lossy(&text[..end]).trim().to_string();
    (!brand.is_empty()).then_some(brand)
}

/// A zeroed plain C struct.
fn unsafe_zeroed<T: Copy>() -> T {
    // SAFETY: only used for libc's plain-data structs, for which all-zero bytes are valid.
    unsafe { std::mem::zeroed() }
}
