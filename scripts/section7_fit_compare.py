#!/usr/bin/env python3
"""The as-built fit from the calibrated stack against the fit from the raw frames, per camera of a
Section 7 run (scripts/experiments_section7.sh): fitted minus true for each parameter, with the raw
fit's curvature and jackknife sigma, its reduced chi^2 and whether it calls its sigma reliable.
Reads OUT/<camera>/asbuilt/truth.json, OUT/<camera>/fitted/fit.json and
OUT/<camera>/fitted_raw/fit.json; prints a Markdown table.
Usage: scripts/section7_fit_compare.py OUT CAMERA [CAMERA ...]"""
import json
import pathlib
import sys

if len(sys.argv) < 3:
    sys.exit(__doc__)
out = pathlib.Path(sys.argv[1])
names = ["level1", "level2", "level3", "z", "dx", "dy"]


def params(path):
    f = json.loads(path.read_text())
    return f, {p["name"]: p for p in f["parameters"]}


def scale(name):
    return (1e9, "nm") if name.startswith("level") else (1e6, "µm")


print("| camera | parameter | true | stack fit − true | raw fit − true | raw σ (curvature) | raw σ (jackknife) |")
print("|---|---|---:|---:|---:|---:|---:|")
notes = []
for cam in sys.argv[2:]:
    truth = json.loads((out / cam / "asbuilt" / "truth.json").read_text())["fit_parameters"]
    _, stack = params(out / cam / "fitted" / "fit.json")
    raw_file, raw = params(out / cam / "fitted_raw" / "fit.json")
    for n in names:
        k, unit = scale(n)
        t = truth[n]
        jk = raw[n].get("sigma_jackknife")
        print(f"| {cam} | {n} ({unit}) | {t * k:.2f} | {(stack[n]['value'] - t) * k:+.2f} | {(raw[n]['value'] - t) * k:+.2f} | "
              f"{raw[n]['sigma'] * k:.3f} | {'' if jk is None else f'{jk * k:.3f}'} |")
    notes.append(f"{cam}: the raw fit's reduced chi^2 {raw_file.get('chi2_reduced', float('nan')):.3f}, "
                 f"sigma reliable: {str(raw_file.get('sigma_reliable')).lower()}")
print()
for line in notes:
    print("- " + line)
