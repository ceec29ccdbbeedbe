#!/usr/bin/python3
"""Makes seeds for the Zarr fuzz harnesses (input formats in fuzz/zarr_fuzz_inputs.h) from stores
written by tests/io/fixtures/write_zarr_fixtures.py.

Usage: write_zarr_fixtures.py FIXTURES && make_seeds.py FIXTURES fuzz/zarr/seeds
"""
import os
import struct
import sys

fixtures, out = sys.argv[1], sys.argv[2]
for sub in ("zarr_metadata", "chunk_codec", "zarr_store"):
    os.makedirs(os.path.join(out, sub), exist_ok=True)


def read(path):
    with open(path, "rb") as f:
        return f.read()


def save(sub, name, data):
    with open(os.path.join(out, sub, name), "wb") as f:
        f.write(data)


CODEC = {"blosc": 0, "zstd": 1, "zlib": 2, "gzip": 3, "lz4": 4}
small = ["dtype-le-u2", "compressor-blosc-lz4-bitshuffle", "compressor-zstd", "compressor-zlib",
         "compressor-gzip", "compressor-lz4", "compressor-none", "order-f", "separator-slash",
         "axes-tczyx", "missing-chunks", "multiscale", "v3-zstd-crc32c", "v3-sharded",
         "v3-sharded-index-start", "v3-transpose", "v3-multiscale"]
for name in small:
    store = os.path.join(fixtures, name + ".ome.zarr")
    array = os.path.join(store, "0")
    meta_file = next(f for f in (os.path.join(array, ".zarray"), os.path.join(array, "zarr.json"))
                     if os.path.exists(f))
    meta = read(meta_file)
    attrs_file = os.path.join(store, ".zattrs")
    attrs = read(attrs_file) if os.path.exists(attrs_file) else read(os.path.join(store, "zarr.json"))
    save("zarr_metadata", name + "-array", b"\0" + meta)
    save("zarr_metadata", name + "-attrs", b"\1" + attrs)
    files = []
    for root, _, names in os.walk(array):
        for n in sorted(names):
            if n in (".zarray", "zarr.json", ".zattrs"):
                continue
            rel = os.path.relpath(os.path.join(root, n), array)
            files.append((rel, read(os.path.join(root, n))))
    files = files[:6]  # A few chunks keep seeds small; the others read as missing.
    store_seed = b"@@@@".join([attrs if name.startswith("v3") is False else b"", meta] +
                              [rel.encode() + b"\n" + data for rel, data in files])
    save("zarr_store", name, store_seed)
    if not name.startswith("v3") and files:
        import json
        compressor = json.loads(meta).get("compressor")
        if compressor and compressor["id"] in CODEC:
            chunks = json.loads(meta)["chunks"]
            size = 1
            for c in chunks:
                size *= c
            size *= int(json.loads(meta)["dtype"][2:])
            header = bytes([CODEC[compressor["id"]]]) + struct.pack("<I", size)[:3] + b"\x02"
            save("chunk_codec", name, header + files[0][1])
