/* ProcessPrng for Debian's wine 8.0, which lacks bcryptprimitives.dll: Rust's standard library
 * (1.78 and newer) draws its random seeds from it on Windows 10 and later, where the DLL is
 * part of the system. Only CI's wine prefix gets this stand-in; it forwards to RtlGenRandom
 * (advapi32's SystemFunction036), which wine has. Built by .ci/cross with mingw-w64. */
#include <windows.h>
BOOLEAN WINAPI SystemFunction036(PVOID buffer, ULONG length);
BOOL WINAPI ProcessPrng(PBYTE data, SIZE_T len) {
    while (len > 0) {
        ULONG chunk = len > 0x40000000 ? 0x40000000 : (ULONG)len;
        if (!SystemFunction036(data, chunk)) return FALSE;
        data += chunk; len -= chunk;
    }
    return TRUE;
}
