#!/usr/bin/env python3
"""Writes the DICOM fuzz seeds in tests/fuzz/corpus/dicom: tiny files (under 1 KB), valid in each
encoding the loader reads and broken in the ways scans break. Re-run after changing it:
    python3 tests/fuzz/make_dicom_seeds.py
No third-party modules; the files are built byte by byte like tests/host_viz/volume/dicom_bytes.hpp."""
import os
import struct

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus", "dicom")
LONG_VRS = {b"OB", b"OD", b"OF", b"OL", b"OV", b"OW", b"SQ", b"SV", b"UC", b"UN", b"UR", b"UT", b"UV"}
EXPLICIT_LE, IMPLICIT_LE, EXPLICIT_BE, RLE = "1.2.840.10008.1.2.1", "1.2.840.10008.1.2", "1.2.840.10008.1.2.2", "1.2.840.10008.1.2.5"


class DataSet:
    def __init__(self, explicit=True, big=False):
        self.explicit, self.big, self.b = explicit, big, b""

    def _u16(self, v):
        return struct.pack(">H" if self.big else "<H", v)

    def _u32(self, v):
        return struct.pack(">I" if self.big else "<I", v)

    def header(self, g, e, vr, length):
        self.b += self._u16(g) + self._u16(e)
        if not self.explicit:
            self.b += self._u32(length)
        elif vr in LONG_VRS:
            self.b += vr + b"\0\0" + self._u32(length)
        else:
            self.b += vr + self._u16(length)
        return self

    def el(self, g, e, vr, value, pad=b" "):
        if len(value) % 2:
            value += pad
        self.header(g, e, vr, len(value))
        self.b += value
        return self

    def us(self, g, e, v):
        return self.el(g, e, b"US", self._u16(v))

    def uid(self, g, e, v):
        return self.el(g, e, b"UI", v.encode(), b"\0")

    def seq(self, g, e, items, undefined_items=False):
        self.header(g, e, b"SQ", 0xFFFFFFFF)
        for it in items:
            self.b += self._u16(0xFFFE) + self._u16(0xE000)
            if undefined_items:
                self.b += self._u32(0xFFFFFFFF) + it.b + self._u16(0xFFFE) + self._u16(0xE00D) + self._u32(0)
            else:
                self.b += self._u32(len(it.b)) + it.b
        self.b += self._u16(0xFFFE) + self._u16(0xE0DD) + self._u32(0)
        return self

    def fragments(self, frags):
        self.header(0x7FE0, 0x0010, b"OB", 0xFFFFFFFF)
        self.b += self._u16(0xFFFE) + self._u16(0xE000) + self._u32(0)
        for f in frags:
            self.b += self._u16(0xFFFE) + self._u16(0xE000) + self._u32(len(f)) + f
        self.b += self._u16(0xFFFE) + self._u16(0xE0DD) + self._u32(0)
        return self


def part10(ts, ds):
    meta = DataSet()
    meta.el(0x0002, 0x0001, b"OB", b"\0\1", b"\0").uid(0x0002, 0x0002, "1.2.840.10008.5.1.4.1.1.2")
    meta.uid(0x0002, 0x0003, "1.2.3.4").uid(0x0002, 0x0010, ts)
    gl = DataSet().el(0x0002, 0x0000, b"UL", struct.pack("<I", len(meta.b)))
    return b"\0" * 128 + b"DICM" + gl.b + meta.b + ds.b


def image_header(ds, rows=3, cols=4, bits=16, signed=1, modality="CT", z=0.0, frames=None, samples=1, photometric="MONOCHROME2"):
    ds.el(0x0008, 0x0060, b"CS", modality.encode()).uid(0x0020, 0x000E, "1.2.826.0.1.9")
    ds.el(0x0020, 0x0032, b"DS", ("-10\\-20\\%g" % z).encode()).el(0x0020, 0x0037, b"DS", b"1\\0\\0\\0\\1\\0")
    ds.us(0x0028, 0x0002, samples).el(0x0028, 0x0004, b"CS", photometric.encode())
    if frames is not None:
        ds.el(0x0028, 0x0008, b"IS", str(frames).encode())
    ds.us(0x0028, 0x0010, rows).us(0x0028, 0x0011, cols).el(0x0028, 0x0030, b"DS", b"0.5\\0.5")
    ds.us(0x0028, 0x0100, bits).us(0x0028, 0x0101, bits).us(0x0028, 0x0102, bits - 1).us(0x0028, 0x0103, signed)
    ds.el(0x0028, 0x1052, b"DS", b"-1024").el(0x0028, 0x1053, b"DS", b"1")
    return ds


def pixels(n):
    return bytes((i * 37 + 11) & 0xFF for i in range(n))


def native(explicit=True, big=False, rows=3, cols=4, bits=16, nbytes=None, **kw):
    ds = image_header(DataSet(explicit, big), rows, cols, bits, **kw)
    n = rows * cols * bits // 8 if nbytes is None else nbytes
    return ds.el(0x7FE0, 0x0010, b"OW" if bits == 16 else b"OB", pixels(n), b"\0")


def packbits(data):
    out = b""
    for i in range(0, len(data), 128):
        chunk = data[i:i + 128]
        out += bytes([len(chunk) - 1]) + chunk
    return out + (b"\0" if len(out) % 2 else b"")


def rle_frame(rows, cols):
    values = [(i * 37 - 300) & 0xFFFF for i in range(rows * cols)]
    hi = packbits(bytes(v >> 8 for v in values))
    lo = packbits(bytes(v & 0xFF for v in values))
    header = struct.pack("<16I", 2, 64, 64 + len(hi), *([0] * 13))
    return header + hi + lo


def main():
    os.makedirs(OUT, exist_ok=True)
    seeds = {}
    seeds["valid_explicit_le.dcm"] = part10(EXPLICIT_LE, native())
    seeds["valid_implicit_le.dcm"] = part10(IMPLICIT_LE, native(explicit=False))
    seeds["valid_explicit_be.dcm"] = part10(EXPLICIT_BE, native(big=True))
    seeds["valid_u8_mr.dcm"] = part10(EXPLICIT_LE, native(bits=8, signed=0, modality="MR"))
    item = DataSet().uid(0x0008, 0x1150, "1.2.840.10008.5.1.4.1.1.2").uid(0x0008, 0x1155, "1.2.3.4.5")
    nested = DataSet().seq(0x0008, 0x1140, [item, item], undefined_items=True)
    ds = DataSet().seq(0x0008, 0x1115, [nested])
    ds.b += native().b
    seeds["valid_sequences.dcm"] = part10(EXPLICIT_LE, ds)
    ids = DataSet(explicit=False).seq(0x0008, 0x1140, [DataSet(explicit=False).uid(0x0008, 0x1155, "1.2.3")])
    ids.b += native(explicit=False).b
    seeds["valid_implicit_sequence.dcm"] = part10(IMPLICIT_LE, ids)
    seeds["valid_rle.dcm"] = part10(RLE, image_header(DataSet()).fragments([rle_frame(3, 4)]))
    full = seeds["valid_explicit_le.dcm"]
    seeds["broken_cut_in_meta.dcm"] = full[:200]
    seeds["broken_cut_in_header.dcm"] = full[:len(full) - 70]
    seeds["broken_cut_in_pixels.dcm"] = full[:-7]
    seeds["broken_short_pixels.dcm"] = part10(EXPLICIT_LE, native(nbytes=10))
    bad_vr = bytearray(full)
    at = bad_vr.find(b"\x08\x00\x60\x00CS")
    bad_vr[at + 4:at + 6] = b"zz"
    seeds["broken_bad_vr.dcm"] = bytes(bad_vr)
    # The fuzzer's first find: GDCM's RLE decoder read out of bounds (SIGSEGV) when the RLE header
    # claims 0x00100002 segments. decode_rle_frame refuses it.
    bad_rle = bytearray(seeds["valid_rle.dcm"])
    at = bad_rle.find(struct.pack("<3I", 2, 64, 64 + len(packbits(bytes(12)))))
    assert at > 0
    bad_rle[at:at + 4] = struct.pack("<I", 0x00100002)
    seeds["broken_rle_segment_count.dcm"] = bytes(bad_rle)
    seeds["broken_rle_no_fragment.dcm"] = part10(RLE, image_header(DataSet()).fragments([]))
    # Compressed data GDCM's codecs must decode (in a child process): not valid streams, only their
    # start markers, so the fuzzer reaches the codecs' error paths.
    for name, ts, frag in [("jpeg_lossless", "1.2.840.10008.1.2.4.70", b"\xff\xd8\xff\xc3\x00\x0b\x10\x00\x03\x00\x04\x01\x01\x11\x00\xff\xd9"),
                           ("jpeg_ls", "1.2.840.10008.1.2.4.80", b"\xff\xd8\xff\xf7\x00\x0b\x10\x00\x03\x00\x04\x01\x01\x11\x00\xff\xd9"),
                           ("jpeg2000", "1.2.840.10008.1.2.4.90", b"\xff\x4f\xff\x51\x00\x29\x00\x00\x00\x00\x00\x04\x00\x00\x00\x03\xff\xd9\x00")]:
        seeds["garbage_%s.dcm" % name] = part10(ts, image_header(DataSet()).fragments([frag + (b"\0" if len(frag) % 2 else b"")]))
    seeds["unsupported_multiframe.dcm"] = part10(EXPLICIT_LE, native(frames=2, nbytes=48))
    seeds["unsupported_rgb.dcm"] = part10(EXPLICIT_LE, native(bits=8, samples=3, photometric="RGB", nbytes=36))
    seeds["unsupported_32bit.dcm"] = part10(EXPLICIT_LE, native(bits=32))
    seeds["not_an_image.dcm"] = part10(EXPLICIT_LE, DataSet().el(0x0008, 0x0060, b"CS", b"SR").uid(0x0020, 0x000E, "1.2.826.0.1.9"))
    seeds["not_dicom.dcm"] = b"This is not a DICOM file, just text named .dcm.\n" * 4
    for name, data in sorted(seeds.items()):
        assert len(data) < 1024, name
        with open(os.path.join(OUT, name), "wb") as f:
            f.write(data)
    print("wrote %d seeds to %s" % (len(seeds), OUT))


if __name__ == "__main__":
    main()
