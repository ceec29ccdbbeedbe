#!/usr/bin/python3
"""The table of bench/vtk_compare.sh from its results.jsonl (medians over repeated runs), and
with a second argument the speed-vs-error plot of the per-frame figures as SVG."""
import json
import math
import statistics
import sys


def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def fmt(v, digits=0):
    return "–" if v is None else f"{v:.{digits}f}"


def ratio(a, b):
    return a / b if a and b else None


def frame_ms(stats):
    """A steady frame's wall time, with the upsampling of a reduced scale (--scale)."""
    ms = stats.get("ms_last_frame")
    return None if ms is None else ms + stats.get("ms_upsample", 0)


def frame_cpu_s(stats):
    cpu = stats.get("cpu_s_last_frame")
    return None if cpu is None else cpu + stats.get("ms_upsample", 0) / 1e3


def short_label(label):
    """The plot's label of a table row."""
    if label.startswith("VTK vtkFixed"):
        return "VTK CPU caster"
    if label.startswith("VTK vtkGPU"):
        return "VTK GPU caster (llvmpipe)"
    if label.startswith("Octoscope, steady frame"):
        return "lossless"
    return label.removeprefix("Octoscope, steady, ").removesuffix(" (opt-in, lossy)")


def scale_and_step(label):
    """(scale, step) of a short Octoscope label ("lossless", "step 2", "scale 0.6, step 2")."""
    scale, step = 1.0, 1.0
    for part in label.split(", "):
        if part.startswith("scale "):
            scale = float(part.split()[1])
        elif part.startswith("step "):
            step = float(part.split()[1])
    return scale, step


def nice_bounds(lo, hi):
    """The 1-2-5 values just below lo and just above hi."""
    steps = [m * 10 ** e for e in range(-1, 7) for m in (1, 2, 5)]
    return max(v for v in steps if v <= lo), min(v for v in steps if v >= hi)


def write_svg(path, panels):
    """Speed vs error, one panel per mode: x = frame ms (log), y = PSNR dB; `panels`: (mode,
    [(label, frame ms, psnr, kind)]) with kind "vtk" or "octoscope". Octoscope's settings are
    drawn as one line per step through its scales, each point labelled with its scale."""
    points = [p for _, pts in panels for p in pts if p[1] and p[2] is not None]
    if not points:
        return
    x_lo, x_hi = nice_bounds(min(p[1] for p in points) * 0.9, max(p[1] for p in points) * 1.1)
    y_lo = 5 * math.floor(min(p[2] for p in points) / 5)
    y_hi = max(5 * math.ceil(max(p[2] for p in points) / 5), y_lo + 5)  # Never an empty range.
    width, height, pad, top, bottom = 480, 460, 60, 40, 50
    colours = {1.0: "#36c", 2.0: "#2a2"}
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width * len(panels)}" '
           f'height="{height}" font-family="sans-serif" font-size="11">',
           f'<rect width="{width * len(panels)}" height="{height}" fill="white"/>']
    for n, (mode, pts) in enumerate(panels):
        x0, x1 = n * width + pad, (n + 1) * width - 20
        y0, y1 = height - bottom, top

        def px(ms):
            return x0 + (math.log10(ms) - math.log10(x_lo)) / (
                math.log10(x_hi) - math.log10(x_lo)) * (x1 - x0)

        def py(db):
            return y0 - (db - y_lo) / (y_hi - y_lo) * (y0 - y1)

        svg.append(f'<text x="{(x0 + x1) / 2}" y="22" text-anchor="middle" font-size="14">'
                   f'{mode.upper()}: steady 1024² frame against error</text>')
        for v in [m * 10 ** e for e in range(0, 6) for m in (1, 2, 5)]:
            if x_lo <= v <= x_hi:
                svg.append(f'<line x1="{px(v):.1f}" y1="{y0}" x2="{px(v):.1f}" y2="{y1}" '
                           'stroke="#ddd"/>')
                svg.append(f'<text x="{px(v):.1f}" y="{y0 + 14}" text-anchor="middle">'
                           f'{v:g}</text>')
        for db in range(y_lo, y_hi + 1, 5):
            svg.append(f'<line x1="{x0}" y1="{py(db):.1f}" x2="{x1}" y2="{py(db):.1f}" '
                       'stroke="#ddd"/>')
            svg.append(f'<text x="{x0 - 6}" y="{py(db) + 4:.1f}" text-anchor="end">{db}</text>')
        svg.append(f'<text x="{(x0 + x1) / 2}" y="{height - 12}" text-anchor="middle">'
                   'frame ms (log; faster to the left)</text>')
        svg.append(f'<text x="{x0 - 40}" y="{(y0 + y1) / 2}" text-anchor="middle" '
                   f'transform="rotate(-90 {x0 - 40} {(y0 + y1) / 2})">PSNR dB against the CPU '
                   'reference (higher is better)</text>')
        # Octoscope: one line per step through its scales (labelled left for step 1, right for
        # the others, so the two series do not write over each other); the legend bottom right.
        series = {}
        for label, ms, db, kind in pts:
            if kind == "octoscope" and ms and db is not None:
                scale, step = scale_and_step(label)
                series.setdefault(step, []).append((scale, ms, db, label))
        for k, (step, members) in enumerate(sorted(series.items())):
            members.sort()
            colour = colours.get(step, "#888")
            line = " ".join(f"{px(ms):.1f},{py(db):.1f}" for _, ms, db, _ in members)
            svg.append(f'<polyline points="{line}" fill="none" stroke="{colour}"/>')
            for scale, ms, db, label in members:
                x, y = px(ms), py(db)
                fill = colour if label == "lossless" else "white"
                svg.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="4.5" fill="{fill}" '
                           f'stroke="{colour}" stroke-width="2"/>')
                text = label if label == "lossless" else f"×{scale:g}"
                if k == 0:
                    svg.append(f'<text x="{x - 8:.1f}" y="{y + 4:.1f}" text-anchor="end" '
                               f'fill="{colour}">{text}</text>')
                else:
                    svg.append(f'<text x="{x + 8:.1f}" y="{y + 4:.1f}" fill="{colour}">'
                               f'{text}</text>')
            svg.append(f'<text x="{x1 - 4}" y="{y0 - 8 - 14 * k}" text-anchor="end" '
                       f'fill="{colour}">Octoscope, step {step:g}, ×scale (opt-in below 1)'
                       '</text>')
        for label, ms, db, kind in pts:
            if kind != "vtk" or not ms or db is None:
                continue
            x, y = px(ms), py(db)
            if label == "VTK CPU caster":
                # Its error is the bar a faster setting must reach ("equal or lower error").
                svg.append(f'<line x1="{x0}" y1="{y:.1f}" x2="{x1}" y2="{y:.1f}" '
                           'stroke="#c33" stroke-dasharray="4 3"/>')
            svg.append(f'<rect x="{x - 5:.1f}" y="{y - 5:.1f}" width="10" height="10" '
                       'fill="#c33"/>')
            # Near the right edge the label goes to the left of its point.
            side = (f'x="{x - 8:.1f}" text-anchor="end"' if x > x1 - 150 else f'x="{x + 8:.1f}"')
            svg.append(f'<text {side} y="{y - 6:.1f}" fill="#c33">{label}</text>')
    svg.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(svg) + "\n")


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    out = ["| mode | renderer | first image ms | first image CPU s | frame ms | frame CPU s "
           "| PSNR dB | max diff | VTK CPU caster ÷ this, frame (wall / CPU) "
           "| VTK CPU caster ÷ this, first image (wall / CPU) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    at_vtk_error = ["| mode | as accurate as VTK by | VTK CPU caster, frame and error "
                    "| Octoscope's fastest steady setting that is | its frame and error "
                    "| VTK ÷ it, frame (wall / CPU) |",
                    "|---|---|---|---|---|---|"]
    panels = []
    for mode in ("mip", "dvr"):
        table = []  # label, first ms, first cpu s, frame ms, frame cpu s, psnr, max diff
        for name, label in (("fixed", "VTK vtkFixedPointVolumeRayCastMapper"),
                            ("gpu", "VTK vtkGPUVolumeRayCastMapper (Mesa llvmpipe)")):
            # One result per VTK process: its times scatter from process to process (up to 2x
            # on the same input), so each figure is the median over the processes.
            runs = [r["result"] for r in rows if r["renderer"] == "vtk"
                    and r["result"]["mode"] == mode and r["result"]["mapper"] == name]
            if not runs:
                continue
            label += f" (median of {len(runs)} processes; frames {fmt(min(r['ms_frame_median'] for r in runs))}–{fmt(max(r['ms_frame_median'] for r in runs))} ms)"
            table.append((label, median([r["ms_first_image"] for r in runs]),
                          median([r["cpu_ms_first_image"] / 1e3 for r in runs]),
                          median([r["ms_frame_median"] for r in runs]),
                          median([r["cpu_ms_frame_median"] / 1e3 for r in runs]),
                          median([r.get("psnr_db") for r in runs]),
                          median([r.get("max_diff") for r in runs])))
        mine = [r for r in rows if r["renderer"] == "octoscope" and r["mode"] == mode]
        for r in mine:
            if r["what"].startswith("first image"):
                process = (f" (whole process incl. writing the PNG: {r['ms_process']:.0f} ms)"
                           if "ms_process" in r else "")
                table.append((f"Octoscope, {r['what']}{process}", r["ms_first_image"],
                              r["cpu_s_process"], None, None,
                              r["error"]["psnr_db"], r["error"]["max_diff"]))
        refined = [r for r in mine if r["what"] == "refined"]
        if refined:
            table.append(("Octoscope, refined (final image; CPU: whole process)", None, None,
                          median([r["stats"]["ms_total"] for r in refined]),
                          median([r["cpu_s_process"] for r in refined]),
                          median([r["error"]["psnr_db"] for r in refined]),
                          median([r["error"]["max_diff"] for r in refined])))
        # Steady frames: lossless (step 1, full scale) first, then the opt-in lossy settings in
        # the order measured. Frame = the last frame plus the upsampling of a reduced scale.
        steady_rows = []  # Rows of the table (as below): the lossless one and the lossy ones.
        for what in dict.fromkeys(r["what"] for r in mine if r["what"].startswith("steady")):
            steady = [r for r in mine if r["what"] == what and r["stats"].get("final")]
            if not steady:
                continue
            if what == "steady":
                label = "Octoscope, steady frame (all bricks resident: the refined image re-rendered)"
            else:
                label = f"Octoscope, {what} (opt-in, lossy)"
            row = (label, None, None,
                   median([frame_ms(r["stats"]) for r in steady]),
                   median([frame_cpu_s(r["stats"]) for r in steady]),
                   median([r["error"]["psnr_db"] for r in steady]),
                   median([r["error"]["max_diff"] for r in steady]))
            table.append(row)
            steady_rows.append(row)
        panels.append((mode, [(short_label(row[0]), row[3], row[5],
                               "vtk" if row[0].startswith("VTK") else "octoscope")
                              for row in table if row[0].startswith("VTK") or row in steady_rows]))
        base = table[0] if table and table[0][0].startswith("VTK vtkFixed") else None
        if base is not None and base[5] is not None:
            # The comparison at equal or lower error: the fastest steady setting (lossless or
            # lossy) whose PSNR is at least VTK's CPU caster's (median over its processes); and
            # the fastest whose max difference is at most VTK's too.
            for criterion, fits in (
                    ("PSNR", lambda row: row[5] >= base[5]),
                    ("PSNR and max diff", lambda row: row[5] >= base[5] and row[6] <= base[6])):
                fit = [row for row in steady_rows if row[3] is not None and fits(row)]
                if fit:
                    best = min(fit, key=lambda row: row[3])
                    at_vtk_error.append(
                        f"| {mode} | {criterion} | {fmt(base[3])} ms, {fmt(base[5], 1)} dB, max "
                        f"{fmt(base[6])} | {best[0].removeprefix('Octoscope, ')} "
                        f"| {fmt(best[3])} ms, {fmt(best[5], 1)} dB, max {fmt(best[6])} "
                        f"| **{fmt(ratio(base[3], best[3]), 2)}×** / "
                        f"{fmt(ratio(base[4], best[4]), 2)}× |")
                else:
                    at_vtk_error.append(f"| {mode} | {criterion} | {fmt(base[3])} ms, "
                                        f"{fmt(base[5], 1)} dB, max {fmt(base[6])} | no setting "
                                        "measured is as accurate | – | – |")
        for label, first, first_cpu, frame, cpu, psnr, max_diff in table:
            frame_ratio = first_ratio = "–"
            if base is not None:
                frame_ratio = f"{fmt(ratio(base[3], frame), 2)} / {fmt(ratio(base[4], cpu), 2)}"
                first_ratio = (f"{fmt(ratio(base[1], first), 1)} / "
                               f"{fmt(ratio(base[2], first_cpu), 1)}")
            out.append(f"| {mode} | {label} | {fmt(first)} | {fmt(first_cpu, 1)} | {fmt(frame)} "
                       f"| {fmt(cpu, 1)} | {fmt(psnr, 1)} | {fmt(max_diff)} | {frame_ratio} "
                       f"| {first_ratio} |")
    print("\n".join(out))
    if len(sys.argv) > 2:
        write_svg(sys.argv[2], panels)
    if len(at_vtk_error) > 2:
        print("\nAt equal or lower error (against the CPU reference; medians):\n")
        print("\n".join(at_vtk_error))


if __name__ == "__main__":
    main()
