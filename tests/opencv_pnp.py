#!/usr/bin/env python3
"""OpenCV's planar PnP (IPPE and SQPnP) on the same detected hole pixels as
`outlet eval`, for comparison with our pose modes.

Input: the `pose_inputs.jsonl` that `outlet eval` writes, one object per correct
detection: {"model_mm": [[x, y], ...], "pixels": [[u, v], ...], "camera_matrix": [9],
"distortion": [5], "truth_m": [[x, y, z], ...]}.
Output (stdout): one JSON object {"ippe": {...}, "sqpnp": {...}} with, per method,
the hole position error RMS and p95 (mm) and the number of images solved.
"""

import json
import sys

import cv2
import numpy as np


def solve(line, flag):
    model = np.array([[x / 1000.0, y / 1000.0, 0.0] for x, y in line["model_mm"]], dtype=np.float64)
    pixels = np.array(line["pixels"], dtype=np.float64).reshape(-1, 1, 2)
    k = np.array(line["camera_matrix"], dtype=np.float64).reshape(3, 3)
    dist = np.array(line["distortion"], dtype=np.float64)
    ok, rvec, tvec = cv2.solvePnP(model, pixels, k, dist, flags=flag)
    if not ok:
        return None
    r, _ = cv2.Rodrigues(rvec)
    holes = (r @ model.T).T + tvec.reshape(1, 3)
    return np.linalg.norm(holes - np.array(line["truth_m"]), axis=1) * 1000.0


def main(path):
    methods = {"ippe": cv2.SOLVEPNP_IPPE, "sqpnp": cv2.SOLVEPNP_SQPNP}
    errors = {name: [] for name in methods}
    solved = {name: 0 for name in methods}
    with open(path) as f:
        lines = [json.loads(l) for l in f if l.strip()]
    for line in lines:
        for name, flag in methods.items():
            e = solve(line, flag)
            if e is not None and np.all(np.isfinite(e)):
                errors[name].extend(e.tolist())
                solved[name] += 1
    out = {}
    for name in methods:
        e = np.array(errors[name])
        out[name] = {
            "images": len(lines),
            "solved": solved[name],
            "rms_mm": float(np.sqrt(np.mean(e**2))) if e.size else None,
            "p95_mm": float(np.percentile(e, 95)) if e.size else None,
            "median_mm": float(np.median(e)) if e.size else None,
        }
    out["opencv"] = cv2.__version__
    print(json.dumps(out))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: opencv_pnp.py POSE_INPUTS.jsonl")
    main(sys.argv[1])
