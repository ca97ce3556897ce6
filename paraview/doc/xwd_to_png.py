"""XWD (what Xvfb -fbdir keeps, 24/32-bit TrueColor) to PNG, optionally cropped.
Usage: python3 xwd_to_png.py SCREEN.xwd OUT.png [x0,y0,x1,y1]. Standard library only."""
import struct
import sys
import zlib


def read_xwd(path):
    """(width, height, rows of RGB bytes). The header is 25 big-endian 32-bit fields (X11's
    XWDFileHeader), then the window name, then ncolors 12-byte colour entries, then pixels."""
    with open(path, "rb") as f:
        data = f.read()
    h = struct.unpack(">25I", data[:100])
    header_size, width, height = h[0], h[4], h[5]
    byte_order, bits_per_pixel, bytes_per_line, ncolors = h[7], h[11], h[12], h[19]
    masks = h[14:17]
    if bits_per_pixel != 32:
        sys.exit("%s: %d bits per pixel; only 32 is handled" % (path, bits_per_pixel))
    shifts = [(m & -m).bit_length() - 1 for m in masks]
    fmt = ("<" if byte_order == 0 else ">") + "%dI" % width
    start = header_size + 12 * ncolors
    rows = []
    for y in range(height):
        line = struct.unpack_from(fmt, data, start + y * bytes_per_line)
        rows.append(bytes(b for px in line for b in (
            (px & masks[0]) >> shifts[0], (px & masks[1]) >> shifts[1], (px & masks[2]) >> shifts[2])))
    return width, height, rows


def write_png(path, width, height, rows):
    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    raw = b"".join(b"\0" + r for r in rows)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


width, height, rows = read_xwd(sys.argv[1])
if len(sys.argv) > 3:
    x0, y0, x1, y1 = (int(v) for v in sys.argv[3].split(","))
    rows = [r[3 * x0:3 * x1] for r in rows[y0:y1]]
    width, height = x1 - x0, y1 - y0
write_png(sys.argv[2], width, height, rows)
