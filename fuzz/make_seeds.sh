#!/usr/bin/env bash
# Regenerates the seed corpora in fuzz/seeds/ from the fixtures (the seeds are checked in;
# run this only after a format change). Needs python3 and builds the `shearwarp` CLI.
#
#   swv_render/    .swv files of tiny volumes cut from the fixtures, encoded by the CLI
#                  with different shading, lights and thresholds (u8 and u16 sources)
#   sidecar_load/  FLAGS + sidecar JSON + NUL + data, see fuzz_targets/sidecar_load.rs
#   tfspec/        transfer-function, vector and size strings
#   tffile/        transfer-function files (JSON schema of frontends/file/src/tffile.rs)
#   dense_render/  unclassified volumes with tables, lighting, view and mode (the byte
#                  layout of fuzz_targets/dense_render.rs)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(dirname "$here")"
seeds="$here/seeds"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

cargo build --release -q -p shearwarp-file --manifest-path "$root/Cargo.toml"
cli="$root/target/release/shearwarp"

mkdir -p "$seeds/swv_render" "$seeds/sidecar_load" "$seeds/tfspec" "$seeds/tffile"

# Tiny volumes with sidecars, cut from the fixtures.
python3 - "$root/fixtures" "$tmp" <<'PY'
import gzip, json, struct, sys
fx, out = sys.argv[1], sys.argv[2]

def sample(data, dims, step, size, bpv=1):
    nx, ny, nz = dims
    sx, sy, sz = step
    ox, oy, oz = size
    res = bytearray()
    for z in range(oz):
        for y in range(oy):
            for x in range(ox):
                i = ((z * sz) * ny + y * sy) * nx + x * sx
                res += data[i * bpv:(i + 1) * bpv]
    return bytes(res)

def save(name, dims, spacing, data, vtype):
    fname = f"{name}.{vtype}.raw"
    with open(f"{out}/{fname}", "wb") as f:
        f.write(data)
    side = {"name": name, "dims_xyz": list(dims), "spacing_mm_xyz": list(spacing),
            "files": {vtype: {"file": fname, "voxel_type": vtype,
                              "bytes_uncompressed": len(data)}}}
    with open(f"{out}/{name}.json", "w") as f:
        json.dump(side, f)

head = open(f"{fx}/mr_head_colin27_64.u8.raw", "rb").read()
save("head16", (16, 16, 16), (11.3125, 13.5625, 11.3125),
     sample(head, (64, 64, 64), (4, 4, 4), (16, 16, 16)), "u8")
brain = open(f"{fx}/mr_brain_colin27_hires_64.u8.raw", "rb").read()
save("brain12x9x7", (12, 9, 7), (5.0, 6.5, 8.0),
     sample(brain, (64, 64, 64), (5, 7, 9), (12, 9, 7)), "u8")
pd = gzip.open(f"{fx}/mr_pd_brain_series.u16.raw.gz").read()
save("pd8x8x5", (8, 8, 5), (27.5, 27.5, 28.0),
     sample(pd, (256, 256, 20), (32, 32, 4), (8, 8, 5), 2), "u16")
save("dot1", (1, 1, 1), (1.0, 1.0, 1.0), bytes([200]), "u8")
save("line3x1x2", (3, 1, 2), (1.0, 0.5, 2.0), bytes([0, 255, 90, 255, 0, 30]), "u8")
PY

enc() { "$cli" encode "$tmp/$1.json" -o "$seeds/swv_render/$2.swv" "${@:3}"; }
enc head16 head16_shaded --shading
enc head16 head16_unshaded --opacity "0:0,60:0,120:0.6,231:0.9" --min-opacity 0.1
enc brain12x9x7 brain_two_lights --shading --light "1,0,1:#ff8000" --light "-0.5,1,0.2" \
    --gradient-opacity "0:0.2,40:1"
enc pd8x8x5 pd_u16 --shading --u16 --opacity "0:0,200:0.3,1059:1" --ka 0.5 --ks 0
enc dot1 dot --opacity "0:1"
enc line3x1x2 line --shading --opacity "0:0,255:1" --min-opacity 0

# Loader: FLAGS, sidecar, NUL, data (see the target's doc comment for the flag bits).
python3 - "$seeds/sidecar_load" <<'PY'
import gzip, json, sys
out = sys.argv[1]
def seed(name, flags, side, data):
    text = side if isinstance(side, str) else json.dumps(side)
    with open(f"{out}/{name}", "wb") as f:
        f.write(bytes([flags]) + text.encode() + b"\0" + data)
def side(dims, files, spacing=(1.0, 0.5, 2.0)):
    return {"name": "v", "dims_xyz": list(dims), "spacing_mm_xyz": list(spacing), "files": files}
u8 = {"u8": {"file": "v.u8.raw", "voxel_type": "u8", "bytes_uncompressed": 24}}
seed("u8_via_sidecar", 0, side((2, 3, 4), u8), bytes(range(24)))
seed("u8_via_data", 4, side((2, 3, 4), u8), bytes(range(24)))
u16 = {"u16": {"file": "v.u16.raw", "voxel_type": "u16", "bytes_uncompressed": 48}}
seed("u16_prefer", 1 | 8, side((2, 3, 4), u16), bytes(range(48)))
gz = {"u8": {"file": "v.u8.raw.gz", "voxel_type": "u8", "bytes_uncompressed": 8}}
seed("gzip_by_suffix", 2 | 16, side((2, 2, 2), gz), bytes([1, 2, 3, 4, 5, 6, 7, 8]))
seed("gzip_by_magic", 3 | 4 | 16, {"dims_xyz": [2, 2, 2], "spacing_mm_xyz": [1, 1, 1],
     "files": {"x": {"file": "v.raw", "voxel_type": "u8"}}}, bytes(8))
seed("no_files_field", 4, {"dims_xyz": [3, 1, 1], "spacing_mm_xyz": [1e-3, 7, 1e5]}, bytes(3))
both = {"u8": {"file": "v.u8.raw", "voxel_type": "u8"},
        "u16": {"file": "v.u16.raw", "voxel_type": "u16", "bytes_uncompressed": 4}}
seed("two_files", 1 | 8, side((1, 2, 1), both), bytes([0, 1, 2, 3]))
seed("fixture_style", 0, open(sys.argv[1] + "/../../../fixtures/mr_head_colin27_64.json")
     .read().replace("mr_head_colin27_64.u8.raw", "v.u8.raw").replace("64", "2")
     .replace("262144", "8"), bytes(8))
PY

# Transfer functions, vectors and sizes, as on the command line and in the README.
i=0
while IFS= read -r line; do
    printf '%s' "$line" >"$seeds/tfspec/s$i"
    i=$((i + 1))
done <<'TXT'
0:0,40:0,80:0.3,255:0.9
  -10.5 : 1 ,	1e3:0.25 
0:#000000,128:#ff8040,255:#fff
 0 : #F80 , 1.5:#aBcDeF
1,-0.5,2
 -0.5 , 0 ,1e-3 
800x600
64×32
 1 X 16384 
0:0.2,40:1
0:0,200:0.3,1059:1
TXT
# Transfer-function files: each unit, mode and optional field of the schema.
i=0
while IFS= read -r line; do
    printf '%s' "$line" >"$seeds/tffile/t$i.json"
    i=$((i + 1))
done <<'TXT'
{"version": 1, "opacity": [[0, 0], [60, 0], [120, 0.4], [255, 0.9]]}
{"version": 1, "units": "raw", "mode": "composite", "shading": true, "opacity": [[0, 0], [60, 0], [120, 0.4], [255, 0.9]], "color": [[0, "#805040"], [255, "#fffff0"]], "gradient_opacity": [[0, 0.2], [40, 1]]}
{"version": 1, "units": "hu", "opacity": [[150, 0], [300, 0.3], [1500, 0.9]], "color": [[150, "#a06040"], [400, "#f0e0c0"], [1500, "#ffffff"]]}
{"version": 1, "units": "normalized", "mode": "mip", "opacity": [[0, 0], [0.15, 0], [0.4, 0.1], [1, 0.8]]}
{"version": 1, "units": "normalized", "shading": false, "opacity": [[0.2, 0], [0.5, 1e-3], [0.50000001, 1]], "gradient_opacity": [[0, 0], [1e9, 1]]}
TXT
# Dense volumes (the byte layout of fuzz_targets/dense_render.rs): tame sides and spacing,
# a ramp opacity and a warm colour table in Q15, lighting or none, a view, each mode,
# then a ball's voxels.
mkdir -p "$seeds/dense_render"
python3 - "$seeds/dense_render" <<'PY'
import struct, sys
out = sys.argv[1]

def seed(name, side, spacing, wide, gradient, lights, angles, size, mode, iso, ert):
    b = bytes([side - 1] * 3) + bytes(spacing) + bytes([wide, gradient])
    for v in range(256):
        a = 0 if v < 60 else min(32768, (v - 60) * 200)
        c = [min(32768, 128 * v + 8000), min(32768, 100 * v), min(32768, 90 * v)]
        b += struct.pack("<4H", a, *c)
    b += bytes([lights])
    if lights:
        b += bytes([13, 45, 20, 100])  # ka, kd, ks (/64), shininess
        for _ in range(lights):
            b += bytes([180, 170, 240, 255, 255, 255])  # direction (+120 offset), colour
    b += bytes(angles) + bytes([size - 1, size - 1, mode])
    if mode == 2:
        b += bytes([iso])
    b += bytes([ert])
    c = (side - 1) / 2
    for z in range(side):
        for y in range(side):
            for x in range(side):
                r = ((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2) ** 0.5
                v = max(0, min(255, int(255 - 40 * r)))
                b += struct.pack("<H", v * 16) if wide else bytes([v])
    open(f"{out}/{name}", "wb").write(b)

seed("post", 9, [3, 3, 5], 0, 0, 1, [8, 12], 10, 0, 0, 242)
seed("preint", 8, [3, 5, 3], 1, 1, 2, [30, 50], 12, 1, 0, 255)
seed("iso", 7, [3, 3, 3], 0, 0, 1, [5, 90], 9, 2, 120, 250)
seed("unlit", 12, [3, 3, 3], 0, 1, 0, [0, 0], 12, 0, 0, 255)
PY

echo "seeds written to $seeds"
