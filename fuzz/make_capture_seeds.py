#!/usr/bin/env python3
"""Seeds of the capture fuzz targets (fuzz/corpus/capture_png, fuzz/corpus/capture_tiff), written
with the standard library alone so that every byte is known: 16-bit PNGs with the colour chunks
other tools write (gAMA, sRGB, cHRM, iCCP) and TIFFs gray and RGB, little- and big-endian, tiled,
with several pages, with untyped samples.  Usage: python3 fuzz/make_capture_seeds.py"""
import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))


def png(width, height, channels, samples, chunks=()):
    colour = {1: 0, 3: 2}[channels]
    raw = b""
    for y in range(height):
        row = samples[y * width * channels:(y + 1) * width * channels]
        raw += b"\x00" + struct.pack(">%dH" % len(row), *row)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 16, colour, 0, 0, 0))
    for kind, data in chunks:
        out += chunk(kind, data)
    return out + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def tiff(pages, big_endian=False, tiled=False, sample_format=1):
    """pages: list of (width, height, channels, samples); one IFD each, chained."""
    e = ">" if big_endian else "<"
    out = bytearray((b"MM" if big_endian else b"II") + struct.pack(e + "HI", 42, 0))
    prev_link = 4  # where the offset of the next IFD goes
    for width, height, channels, samples in pages:
        if tiled:  # one 16 x 16 tile per 16 x 16 block, zero padded
            tw = th = 16
            tiles = []
            for ty in range(0, height, th):
                for tx in range(0, width, tw):
                    t = []
                    for y in range(ty, ty + th):
                        for x in range(tx, tx + tw):
                            for c in range(channels):
                                t.append(samples[(y * width + x) * channels + c] if y < height and x < width else 0)
                    tiles.append(struct.pack(e + "%dH" % len(t), *t))
            blobs = tiles
        else:
            blobs = [struct.pack(e + "%dH" % len(samples), *samples)]
        offsets = []
        for b in blobs:
            offsets.append(len(out))
            out += b
        if len(out) % 2:
            out += b"\x00"
        bps_at = len(out)
        out += struct.pack(e + "3H", 16, 16, 16)
        off_at = len(out)
        out += struct.pack(e + "%dI" % len(offsets), *offsets)
        cnt_at = len(out)
        out += struct.pack(e + "%dI" % len(blobs), *[len(b) for b in blobs])
        tags = [(256, 4, 1, width), (257, 4, 1, height),
                (258, 3, channels, 16 if channels == 1 else bps_at), (259, 3, 1, 1),
                (262, 3, 1, 2 if channels == 3 else 1), (277, 3, 1, channels), (284, 3, 1, 1),
                (339, 3, 1, sample_format)]
        if tiled:
            tags += [(322, 3, 1, 16), (323, 3, 1, 16), (324, 4, len(blobs), off_at if len(blobs) > 1 else offsets[0]),
                     (325, 4, len(blobs), cnt_at if len(blobs) > 1 else len(blobs[0]))]
        else:
            tags += [(273, 4, 1, offsets[0]), (278, 4, 1, height), (279, 4, 1, len(blobs[0]))]
        tags.sort()
        ifd = len(out)
        struct.pack_into(e + "I", out, prev_link, ifd)
        out += struct.pack(e + "H", len(tags))
        for tag, kind, count, value in tags:
            if kind == 3 and count == 1:
                out += struct.pack(e + "HHIHH", tag, kind, count, value, 0)
            else:
                out += struct.pack(e + "HHII", tag, kind, count, value)
        prev_link = len(out)
        out += struct.pack(e + "I", 0)
    return bytes(out)


def write(folder, name, data):
    d = os.path.join(HERE, "corpus", folder)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def main():
    w, h = 5, 3
    gray = [(i * 977 + 13) % 4096 for i in range(w * h)]  # 12-bit codes
    rgb = [(i * 4099 + 7) % 65536 for i in range(3 * w * h)]
    gama = (b"gAMA", struct.pack(">I", 45455))
    srgb = (b"sRGB", b"\x00")
    chrm = (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))
    iccp = (b"iCCP", b"icc\x00\x00" + zlib.compress(b"\x00" * 132))
    write("capture_png", "seed-gray16-gama.png", png(w, h, 1, gray, [gama]))
    write("capture_png", "seed-gray16-srgb-chrm.png", png(w, h, 1, gray, [srgb, chrm]))
    write("capture_png", "seed-rgb16-iccp.png", png(w, h, 3, rgb, [iccp]))
    write("capture_png", "seed-rgb16-plain.png", png(w, h, 3, rgb))
    write("capture_tiff", "seed-gray16-le.tif", tiff([(w, h, 1, gray)]))
    write("capture_tiff", "seed-gray16-be.tif", tiff([(w, h, 1, gray)], big_endian=True))
    write("capture_tiff", "seed-rgb16-le.tif", tiff([(w, h, 3, rgb)]))
    write("capture_tiff", "seed-gray16-tiled.tif", tiff([(20, 18, 1, [(i * 31) % 4096 for i in range(20 * 18)])], tiled=True))
    write("capture_tiff", "seed-gray16-3pages.tif", tiff([(w, h, 1, gray)] * 3))
    write("capture_tiff", "seed-gray16-untyped.tif", tiff([(w, h, 1, gray)], sample_format=4))


if __name__ == "__main__":
    main()
