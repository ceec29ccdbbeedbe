#!/usr/bin/python3
"""The table of bench/vtk_compare.sh from its results.jsonl (medians over repeated runs)."""
import json
import statistics
import sys


def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def fmt(v, digits=0):
    return "–" if v is None else f"{v:.{digits}f}"


def ratio(a, b):
    return a / b if a and b else None


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    out = ["| mode | renderer | first image ms | first image CPU s | frame ms | frame CPU s "
           "| PSNR dB | max diff | VTK CPU caster ÷ this, frame (wall / CPU) "
           "| VTK CPU caster ÷ this, first image (wall / CPU) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
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
        for what, label in (("steady", "Octoscope, steady frame (all bricks resident: the "
                                       "refined image re-rendered)"),
                            ("steady, step 2", "Octoscope, steady frame, samples 2 voxels apart "
                                               "(opt-in, lossy)")):
            steady = [r for r in mine if r["what"] == what and r["stats"].get("final")]
            if steady:
                table.append((label, None, None,
                              median([r["stats"].get("ms_last_frame") for r in steady]),
                              median([r["stats"].get("cpu_s_last_frame") for r in steady]),
                              median([r["error"]["psnr_db"] for r in steady]),
                              median([r["error"]["max_diff"] for r in steady])))
        base = table[0] if table and table[0][0].startswith("VTK vtkFixed") else None
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


if __name__ == "__main__":
    main()
