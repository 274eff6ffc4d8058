#!/usr/bin/env python3
"""Each matup variant of one or more `matup sweep` results against the sweep's per-map
baselines, as the issues' bars read them, per degradation of the inputs (a sweep's `degrade`):
its mean render PSNR and FLIP, its lead in PSNR over the better of the baselines (material by
material, then averaged), on how many materials it beats every baseline in PSNR and in FLIP,
and its worst material.

    python scripts/sweep-lead.py OUT/results.csv [MORE/results.csv ...]

Rows are told apart by their id ("input/kind settings"); a later file's row of the same id
replaces an earlier one, so baselines run once can serve sweeps run with other builds.
"""
import csv
import sys
from collections import defaultdict


def read_rows(paths):
    rows = {}
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["error"] or not row["render_psnr"]:
                    continue
                rows[row["id"]] = row
    return rows.values()


def main(paths):
    baselines = defaultdict(dict)  # input -> baseline -> (psnr, flip)
    variants = defaultdict(dict)  # (degradation, variant) -> input -> (psnr, flip)
    for row in read_rows(paths):
        material, method = row["id"].split("/", 1)
        degradation = material.split("+", 1)[1] if "+" in material else "clean"
        scores = (float(row["render_psnr"]), float(row["render_flip"]))
        if row["kind"] == "per-map":
            baselines[material][method] = scores
        else:
            variants[(degradation, method)][material] = scores
    if not baselines:
        sys.exit("no per-map baselines in " + ", ".join(paths))
    print("| input | variant | mean PSNR / FLIP | lead dB | ahead PSNR / FLIP | worst |")
    print("|---|---|---|---|---|---|")
    for (degradation, variant), by_material in sorted(variants.items()):
        measured = [m for m in by_material if m in baselines]
        leads, ahead_psnr, ahead_flip = [], 0, 0
        for m in measured:
            psnr, flip = by_material[m]
            best_psnr = max(p for p, _ in baselines[m].values())
            best_flip = min(f for _, f in baselines[m].values())
            leads.append((psnr - best_psnr, m))
            ahead_psnr += psnr > best_psnr
            ahead_flip += flip < best_flip
        n = len(measured)
        mean_psnr = sum(by_material[m][0] for m in measured) / n
        mean_flip = sum(by_material[m][1] for m in measured) / n
        lead = sum(d for d, _ in leads) / n
        worst, worst_material = min(leads)
        print(
            f"| {degradation} | {variant} | {mean_psnr:.3f} / {mean_flip:.4f} | {lead:+.3f} | "
            f"{ahead_psnr} / {ahead_flip} of {n} | {worst_material} {worst:+.2f} |"
        )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
