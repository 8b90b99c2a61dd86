#!/usr/bin/env python3
"""Training curves of a `hood train` run as an SVG: validation objective and % penetrating
(fixed 30-frame rollouts, evaluation objective) and the per-vertex training loss of regular
steps, against iterations. Usage: plot_training.py RUN_DIR OUT.svg"""
import json, math, sys

run, out = sys.argv[1], sys.argv[2]
val = [json.loads(l) for l in open(f"{run}/validation.jsonl")]
win, loss = 250, {}
for l in open(f"{run}/log.jsonl"):
    r = json.loads(l)
    for s in r["steps"]:
        if not s["startup"] and not s["skipped"]:
            loss.setdefault(r["iteration"] // win, []).append(s["total"] / r["vertices"])
loss = sorted((k * win, sorted(v)[len(v) // 2]) for k, v in loss.items() if v)

W, H, M = 900, 260, 60
panels = [
    ("validation objective (J, log)", [(v["iteration"], v["mean_total"]) for v in val if v["mean_total"] > 0], True),
    ("validation % penetrating", [(v["iteration"], v["mean_penetrating_percent"]) for v in val], False),
    ("training loss per vertex, regular steps (J, median per 250 it., log)", loss, True),
]
xmax = max(max(p[0] for p in d) for _, d, _ in panels if d)
svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H * len(panels)}" font-family="sans-serif" font-size="12">']
for i, (title, pts, log) in enumerate(panels):
    y0 = i * H
    f = (lambda y: math.log10(y)) if log else (lambda y: y)
    ys = [f(y) for _, y in pts if (y > 0 or not log)]
    lo, hi = min(ys), max(ys)
    hi = hi if hi > lo else lo + 1
    X = lambda x: M + (W - 2 * M) * x / xmax
    Y = lambda y: y0 + H - M / 2 - (H - M) * (f(y) - lo) / (hi - lo)
    svg.append(f'<text x="{M}" y="{y0 + 18}">{title}</text>')
    svg.append(f'<rect x="{M}" y="{y0 + M / 2}" width="{W - 2 * M}" height="{H - M}" fill="none" stroke="#999"/>')
    for t in range(5):
        v = lo + (hi - lo) * t / 4
        label = f"{10 ** v:.3g}" if log else f"{v:.3g}"
        yy = y0 + H - M / 2 - (H - M) * t / 4
        svg.append(f'<text x="4" y="{yy + 4}">{label}</text>')
    for t in range(6):
        xx = xmax * t / 5
        svg.append(f'<text x="{X(xx) - 10}" y="{y0 + H - 8}">{int(xx)}</text>')
    path = " ".join(f"{X(x):.1f},{Y(y):.1f}" for x, y in pts if (y > 0 or not log))
    svg.append(f'<polyline points="{path}" fill="none" stroke="#2a6fbf" stroke-width="1.5"/>')
svg.append("</svg>")
open(out, "w").write("\n".join(svg))
print(f"wrote {out}")
