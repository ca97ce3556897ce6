#!/usr/bin/env python3
"""Check the abi3 wheels .ci/cross builds: one per platform, each holding the package and an
extension module built for that platform's CPU and format (PE, Mach-O, ELF); the Windows
module must link python3.dll and no versioned pythonXY.dll (the stable ABI).

    python3 .ci/check_wheels.py DIST_FOLDER
"""

import os
import struct
import sys
import zipfile

# Wheel platform tag -> (module file, format, machine) expected inside.
WANT = {
    "win_amd64": ("_t2tf.pyd", "pe", 0x8664),
    "macosx_11_0_arm64": ("_t2tf.abi3.so", "macho", 0x0100000C),
    "macosx_10_12_x86_64": ("_t2tf.abi3.so", "macho", 0x01000007),
    "manylinux2014_aarch64": ("_t2tf.abi3.so", "elf", 183),
}


def machine(data, kind):
    if kind == "pe":
        pe = struct.unpack_from("<I", data, 0x3C)[0]
        if data[pe:pe + 4] != b"PE\0\0":
            raise ValueError("not a PE file")
        return struct.unpack_from("<H", data, pe + 4)[0]
    if kind == "macho":
        magic, cpu = struct.unpack_from("<II", data, 0)
        if magic != 0xFEEDFACF:
            raise ValueError("not a 64-bit Mach-O file")
        return cpu
    if data[:4] != b"\x7fELF":
        raise ValueError("not an ELF file")
    return struct.unpack_from("<H", data, 18)[0]


def main():
    dist = sys.argv[1]
    wheels = sorted(f for f in os.listdir(dist) if f.endswith(".whl"))
    seen = set()
    for wheel in wheels:
        tag = wheel[:-4].split("-")[-1]
        if "cp39-abi3" not in wheel:
            sys.exit(f"{wheel}: not an abi3 wheel for CPython 3.9 and later")
        match = [t for t in WANT if t in tag]
        if not match:
            sys.exit(f"{wheel}: unexpected platform tag {tag}")
        module, kind, want = WANT[match[0]]
        with zipfile.ZipFile(os.path.join(dist, wheel)) as z:
            names = z.namelist()
            for need in ("t2tf/__init__.py", "t2tf/_t2tf.pyi", f"t2tf/{module}"):
                if need not in names:
                    sys.exit(f"{wheel}: lacks {need}")
            data = z.read(f"t2tf/{module}")
        got = machine(data, kind)
        if got != want:
            sys.exit(f"{wheel}: {module} is for machine {got:#x}, not {want:#x}")
        if kind == "pe":
            if b"python3.dll" not in data.lower():
                sys.exit(f"{wheel}: {module} does not link python3.dll")
            for minor in range(6, 20):
                if f"python3{minor}.dll".encode() in data.lower():
                    sys.exit(f"{wheel}: {module} links python3{minor}.dll, not the stable ABI")
        seen.add(match[0])
        print(f"{wheel}: {module} for the right CPU ({len(data) / 1e6:.1f} MB)")
    missing = set(WANT) - seen
    if missing:
        sys.exit(f"no wheel for {', '.join(sorted(missing))}")


if __name__ == "__main__":
    main()
