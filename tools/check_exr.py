#!/usr/bin/env python3
"""Check that a skybake EXR file opens in the reference OpenEXR library and follows the layout.

Reads the file with the official OpenEXR Python bindings (`pip install OpenEXR numpy`, tested with
OpenEXR 3.x), prints its header and channels, and checks: single part, tiled 64x64 with one level,
32-bit float channels named per the spectral layout of Fichet, Pacanowski & Wilkie (JCGT 10(3) 2021),
`spectralLayoutVersion == "1.0"`, `emissiveUnits == "W.m^-2.sr^-1"` when S0 channels exist.

With `--pattern` it also compares every pixel with the analytic pattern that the Rust test
`reference_pattern_file_round_trips` (tests/products/store_exr.rs) writes:

    mkdir -p /tmp/skybake-exr
    SKYBAKE_EXR_SAMPLE_DIR=/tmp/skybake-exr cargo test --release --test products store_exr::reference_pattern
    python tools/check_exr.py --pattern /tmp/skybake-exr/pattern_*.exr

When the `blake3` package is installed it also recomputes the whole-file checksum
(crates/store/src/checksum.rs): blake3 of the file with the 64 hex digits of `skybakeFileBlake3` replaced by
ASCII zeros.

Exit status 0 when every check passes.
"""

import argparse
import re
import sys

import numpy as np
import OpenEXR

try:  # optional: `pip install blake3` to recompute the embedded whole-file checksum
    import blake3
except ImportError:
    blake3 = None

CHANNEL_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)\.(\d+)(?:,(\d+))?nm$")


def fail(message):
    print(f"FAIL: {message}")
    sys.exit(1)


def check_layout(path):
    exr = OpenEXR.File(path, separate_channels=True)
    if len(exr.parts) != 1:
        fail(f"{len(exr.parts)} parts, expected 1")
    header = exr.header()
    channels = exr.channels()
    print(f"OpenEXR library {OpenEXR.OPENEXR_VERSION}: opened {path}, compression {header['compression']}")
    for key in sorted(header):
        value = header[key]
        text = repr(value)
        print(f"  header {key}: {text[:120]}{'...' if len(text) > 120 else ''}")

    tiles = header.get("tiles")
    if tiles is None:
        fail("not a tiled file")
    if (tiles.xSize, tiles.ySize) != (64, 64):
        fail(f"tile size {tiles.xSize}x{tiles.ySize}, expected 64x64")
    if tiles.mode != OpenEXR.ONE_LEVEL:
        fail(f"tile level mode {tiles.mode}, expected ONE_LEVEL")
    if header.get("spectralLayoutVersion") != "1.0":
        fail(f"spectralLayoutVersion = {header.get('spectralLayoutVersion')!r}")

    spectral = {}
    for name, channel in sorted(channels.items()):
        pixels = channel.pixels
        print(f"  channel {name}: {pixels.dtype} {pixels.shape}")
        if pixels.dtype != np.float32:
            fail(f"channel {name} is {pixels.dtype}, expected float32")
        if name in ("R", "G", "B"):
            continue
        match = CHANNEL_RE.match(name)
        if not match:
            fail(f"channel {name!r} does not follow the spectral layout")
        layer, whole, frac = match.groups()
        if frac is None or len(frac) != 6:
            fail(f"channel {name!r}: skybake writes six decimals")
        spectral.setdefault(layer, []).append(float(f"{whole}.{frac}"))
    if not spectral:
        fail("no spectral channels")
    if "S0" in spectral and header.get("emissiveUnits") != "W.m^-2.sr^-1":
        fail(f"emissiveUnits = {header.get('emissiveUnits')!r}")
    checksum = header.get("skybakeFileBlake3", "")
    if not re.fullmatch(r"[0-9a-f]{64}", checksum):
        fail(f"skybakeFileBlake3 = {checksum!r}")
    if blake3 is not None:
        verify_checksum(path, checksum)
    print(f"  layers: { {k: sorted(v) for k, v in spectral.items()} }")
    return header, channels


def verify_checksum(path, stored):
    """Recompute the embedded blake3 independently of the Rust code."""
    data = bytearray(open(path, "rb").read())
    prefix = b"skybakeFileBlake3\0string\0" + (64).to_bytes(4, "little")
    start = data.find(prefix)
    if start < 0:
        fail("checksum attribute not found in the raw bytes")
    offset = start + len(prefix)
    data[offset : offset + 64] = b"0" * 64
    actual = blake3.blake3(bytes(data)).hexdigest()
    if actual != stored:
        fail(f"blake3 {actual} != stored {stored}")
    print(f"  blake3 checksum verified: {actual}")


def check_pattern(header, channels):
    """Recompute the pattern of tests/products/store_exr.rs::reference_pattern_image in float32."""
    height, width = channels["R"].pixels.shape
    if (width, height) != (100, 70):
        fail(f"pattern image is {width}x{height}, expected 100x70")
    y, x = np.mgrid[0:height, 0:width]
    expected = {
        "R": x.astype(np.float32),
        "G": y.astype(np.float32),
        "B": (x * y).astype(np.float32),
    }
    for k, wl in enumerate(["400,000000", "550,500000", "700,250000"]):
        expected[f"S0.{wl}nm"] = (x + 128 * y).astype(np.float32) * np.float32(0.25) + np.float32(k)
        expected[f"T.{wl}nm"] = np.float32((k + 1) * 0.125) + x.astype(np.float32) / np.float32(128)
    if set(expected) != set(channels):
        fail(f"channels {sorted(channels)} != {sorted(expected)}")
    for name, want in expected.items():
        got = channels[name].pixels
        if not np.array_equal(got.view(np.uint32), want.astype(np.float32).view(np.uint32)):
            fail(f"channel {name}: pixel values differ from the pattern")
    attributes = {
        "skybakeSpec": '{"product":"aerial","site":"Z\u00fcrich","wavelengths_nm":[400,550.5,700.25]}',
        "skybakeEngineVersion": "0.1.0",
        "skybakeErrorEstimate": '{"max_rel_error":0.01}',
        "skybakeComputeTimeMs": "12.5",
    }
    for key, want in attributes.items():
        if header.get(key) != want:
            fail(f"attribute {key} = {header.get(key)!r}, expected {want!r}")
    print(f"  pattern: all {len(expected)} channels bit-identical, attributes match")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+")
    parser.add_argument("--pattern", action="store_true", help="compare with the test pattern")
    args = parser.parse_args()
    for path in args.paths:
        header, channels = check_layout(path)
        if args.pattern:
            check_pattern(header, channels)
        print(f"OK {path}")


if __name__ == "__main__":
    main()
