#!/usr/bin/env python3
"""Helper of scripts/bench_vs_apriltag.sh (standard library only).

  bench_vs_apriltag.py place TRUTH.json WIDTH HEIGHT SIZE
      Print "X Y": where a SIZE x SIZE tag goes so that it stays clear of the
      outlet (the holes' box, grown by twice its size and 40 px all round):
      the corner or edge middle farthest from it.

  bench_vs_apriltag.py time-outlet OUTLET REPS IMG...
      Run `taskset -c 0 OUTLET detect --template 2x2 --json IMG...` REPS
      times, and also REPS times on the first image alone; print one JSON
      object: per-image detect ms (median of the runs, from timing_ms.detect),
      found per image, and the wall time of a run over all images and over one.

      With TRUTH_DIR set, also whether each found outlet is right (every true
      hole matched by a reported hole of its kind within 3 px). CPU times are
      the children's user + system time (getrusage).

      Tracking: REPS more runs of `OUTLET detect --track 30` over each image
      repeated TRACK_FRAMES times in a row (a still camera; the first of each
      is a camera jump, searched whole): per image the median detect ms of the
      frames searched in a window, and how many frames a window found.

  bench_vs_apriltag.py summary LABEL OUTLET.json APRIL_D1.txt APRIL_D2.txt
      Print one table row (markdown) and a JSON line with the figures.
"""
import json
import os
import resource
import statistics
import subprocess
import sys
import time


def place(truth, width, height, size):
    with open(truth) as f:
        holes = json.load(f)["holes"]
    xs = [h["pixel"][0] for h in holes]
    ys = [h["pixel"][1] for h in holes]
    w, h = max(xs) - min(xs), max(ys) - min(ys)
    grow = 2 * max(w, h) + 40
    box = (min(xs) - grow, min(ys) - grow, max(xs) + grow, max(ys) + grow)
    m = 8
    cands = []
    for x in (m, (width - size) // 2, width - size - m):
        for y in (m, (height - size) // 2, height - size - m):
            cands.append((x, y))

    def gap(c):
        x0, y0, x1, y1 = c[0], c[1], c[0] + size, c[1] + size
        dx = max(box[0] - x1, x0 - box[2], 0)
        dy = max(box[1] - y1, y0 - box[3], 0)
        return (dx * dx + dy * dy) ** 0.5

    best = max(cands, key=gap)
    if gap(best) <= 0:
        # No place is clear of the grown box: take the one farthest from the holes' centre.
        cx, cy = statistics.mean(xs), statistics.mean(ys)
        best = max(cands, key=lambda c: (c[0] + size / 2 - cx) ** 2 + (c[1] + size / 2 - cy) ** 2)
    print(best[0], best[1])


TRACK_FRAMES = 6


def run_outlet(outlet, images, track=False):
    cmd = ["taskset", "-c", "0", outlet, "detect", "--template", "2x2", "--json"]
    cmd += ["--track", "30"] if track else []
    cmd += images
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    records = [json.loads(line) for line in out.splitlines() if line.strip()]
    if len(records) != len(images):
        sys.exit(f"outlet detect printed {len(records)} records for {len(images)} images")
    return wall * 1e3, cpu * 1e3, records


def correct(record, truth_path):
    """Found, and every true hole matched by a reported hole of its kind within 3 px."""
    if not record.get("found"):
        return False
    with open(truth_path) as f:
        truth = json.load(f)["holes"]
    got = record.get("holes") or []
    for t in truth:
        if not any(
            g["kind"] == t["kind"]
            and (g["pixel"][0] - t["pixel"][0]) ** 2 + (g["pixel"][1] - t["pixel"][1]) ** 2 <= 9
            for g in got
        ):
            return False
    return len(got) == len(truth)


def time_outlet(outlet, reps, images):
    truth_dir = os.environ.get("TRUTH_DIR")
    per_image = [[] for _ in images]
    found = [False] * len(images)
    right = [False] * len(images)
    wall_all, wall_one, cpu_all, cpu_one = [], [], [], []
    # A first run, not counted: the binary's pages, the images in the page cache.
    run_outlet(outlet, images)
    for r in range(reps):
        wall, cpu, records = run_outlet(outlet, images)
        wall_all.append(wall)
        cpu_all.append(cpu)
        for i, rec in enumerate(records):
            if rec.get("error"):
                sys.exit(f"outlet detect failed on {images[i]}: {rec['error']}")
            per_image[i].append(rec["timing_ms"]["detect"])
            if r == 0:
                found[i] = bool(rec["found"])
                if truth_dir:
                    stem = os.path.splitext(os.path.basename(images[i]))[0]
                    right[i] = correct(rec, os.path.join(truth_dir, stem + ".json"))
        wall, cpu, _ = run_outlet(outlet, images[:1])
        wall_one.append(wall)
        cpu_one.append(cpu)
    tracked = [[] for _ in images]
    windows = 0
    for r in range(reps):
        sequence = [img for img in images for _ in range(TRACK_FRAMES)]
        _, _, records = run_outlet(outlet, sequence, track=True)
        for k, rec in enumerate(records):
            if rec.get("searched") in ("window", "followed") and rec.get("found"):
                tracked[k // TRACK_FRAMES].append(rec["timing_ms"]["detect"])
                windows += r == 0
    json.dump(
        {
            "detect_ms": [statistics.median(t) for t in per_image],
            "found": found,
            "right": right,
            "wall_all_ms": statistics.median(wall_all),
            "wall_one_ms": statistics.median(wall_one),
            "cpu_all_ms": statistics.median(cpu_all),
            "cpu_one_ms": statistics.median(cpu_one),
            "n": len(images),
            "track_ms": [statistics.median(t) for t in tracked if t],
            "track_windows": windows,
            "track_frames": len(images) * (TRACK_FRAMES - 1),
        },
        sys.stdout,
    )
    print()


def read_april(path):
    rows = []
    with open(path) as f:
        for line in f:
            _, read_ms, read_cpu, det_ms, det_cpu, ndet, found = line.split()
            rows.append(
                {
                    "read": float(read_ms),
                    "read_cpu": float(read_cpu),
                    "det": float(det_ms),
                    "det_cpu": float(det_cpu),
                    "ndet": int(ndet),
                    "found": int(found),
                }
            )
    return rows


def summary(label, outlet_json, d1, d2):
    with open(outlet_json) as f:
        o = json.load(f)
    a = {1: read_april(d1), 2: read_april(d2)}
    n = o["n"]
    med = statistics.median
    f = {"resolution": label, "n": n}
    f["outlet_detect_ms"] = med(o["detect_ms"])
    # Per image over a batch run: (all images - one image) / (n - 1): reading the
    # PNG, grey conversion, detection and the JSON line; startup and template cancel.
    f["outlet_batch_wall_ms"] = (o["wall_all_ms"] - o["wall_one_ms"]) / (n - 1)
    f["outlet_batch_cpu_ms"] = (o["cpu_all_ms"] - o["cpu_one_ms"]) / (n - 1)
    f["outlet_track_ms"] = med(o["track_ms"]) if o["track_ms"] else float("nan")
    f["outlet_track_windows"] = f"{o['track_windows']}/{o['track_frames']}"
    f["outlet_found"] = sum(o["found"])
    f["outlet_right"] = sum(o["right"])
    for d in (1, 2):
        rows = a[d]
        f[f"april_d{d}_detect_ms"] = med(r["det"] for r in rows)
        f[f"april_d{d}_detect_cpu_ms"] = med(r["det_cpu"] for r in rows)
        f[f"april_d{d}_read_detect_cpu_ms"] = med(r["read_cpu"] + r["det_cpu"] for r in rows)
        f[f"april_d{d}_found"] = sum(r["found"] for r in rows)
        f[f"april_d{d}_other_detections"] = sum(max(r["ndet"] - r["found"], 0) for r in rows)
        f[f"ratio_wall_d{d}"] = f["outlet_detect_ms"] / f[f"april_d{d}_detect_ms"]
        f[f"ratio_cpu_d{d}"] = f["outlet_batch_cpu_ms"] / f[f"april_d{d}_read_detect_cpu_ms"]
        f[f"ratio_track_d{d}"] = f["outlet_track_ms"] / f[f"april_d{d}_detect_ms"]
    print(
        f"| {label} | {n} | {f['outlet_detect_ms']:.2f} | {f['outlet_track_ms']:.2f} "
        f"({f['outlet_track_windows']}) | {f['april_d1_detect_ms']:.2f} / "
        f"{f['april_d2_detect_ms']:.2f} | **{f['ratio_wall_d1']:.2f}** / **{f['ratio_wall_d2']:.2f}** | "
        f"**{f['ratio_track_d1']:.2f}** / **{f['ratio_track_d2']:.2f}** | "
        f"{f['outlet_batch_cpu_ms']:.2f} | {f['april_d1_read_detect_cpu_ms']:.2f} / "
        f"{f['april_d2_read_detect_cpu_ms']:.2f} | **{f['ratio_cpu_d1']:.2f}** / **{f['ratio_cpu_d2']:.2f}** | "
        f"{f['outlet_found']}/{n} ({f['outlet_right']} right) | "
        f"{f['april_d1_found']}/{n}, {f['april_d2_found']}/{n} |"
    )
    print("JSON " + json.dumps(f))


def main():
    if len(sys.argv) >= 2 and sys.argv[1] == "place" and len(sys.argv) == 6:
        place(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
    elif len(sys.argv) >= 5 and sys.argv[1] == "time-outlet":
        time_outlet(sys.argv[2], int(sys.argv[3]), sys.argv[4:])
    elif len(sys.argv) == 6 and sys.argv[1] == "summary":
        summary(*sys.argv[2:])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
