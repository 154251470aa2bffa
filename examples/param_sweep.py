"""A parameter sweep in a loop, written as a table: one technique parameter across values,
with error, GPU time and rays per pixel for each (CSV and Markdown).

    python examples/param_sweep.py --technique reference --param max_depth --values 1 2 4 8
"""

import argparse
import csv
import json
import os

import gilab

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--preset", default="presets/cornell.toml")
parser.add_argument("--size", type=int, default=64)
parser.add_argument("--frames", type=int, default=16)
parser.add_argument("--reference-spp", type=int, default=256)
parser.add_argument("--technique", default="reference")
parser.add_argument("--param", default="max_depth")
parser.add_argument("--values", nargs="+", default=["1", "2", "4", "8"],
                    help="values (JSON literals: 4, 0.5, true, \"name\")")
parser.add_argument("--out", default="out/python-examples")
args = parser.parse_args()
os.makedirs(args.out, exist_ok=True)

spec = {p["name"]: p for p in gilab.params(args.technique)}.get(args.param)
if spec is None:
    raise SystemExit(f"{args.technique} has no parameter '{args.param}'")
print(f"{args.technique}.{args.param}: {spec['doc']} ({spec['kind']}, {spec['min']}..{spec['max']})")

rows = []
with gilab.Session(args.preset, size=args.size) as session:
    reference = session.reference(spp=args.reference_spp)
    for text in args.values:
        value = json.loads(text)
        frame = session.render(args.technique, frames=args.frames, params={args.param: value})
        errors = gilab.metrics.compare(frame.image, reference)
        rows.append({
            args.param: value,
            "relmse": errors["relmse"],
            "flip": errors["flip"],
            "gpu_ms_per_frame": frame.gpu_ms_per_frame,
            "rays_per_pixel": frame.rays_per_pixel,
        })

csv_path = os.path.join(args.out, f"sweep-{args.technique}-{args.param}.csv")
with open(csv_path, "w", newline="") as f:
    writer = csv.DictWriter(f, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
md_path = csv_path[:-4] + ".md"
with open(md_path, "w") as f:
    f.write(f"| {args.param} | relMSE | FLIP | GPU ms/frame | rays/px |\n|---|---|---|---|---|\n")
    for r in rows:
        f.write(f"| {r[args.param]} | {r['relmse']:.4f} | {r['flip']:.4f} | "
                f"{r['gpu_ms_per_frame']:.2f} | {r['rays_per_pixel']:.2f} |\n")
print(open(md_path).read())
print(f"table: {csv_path}, {md_path}")
