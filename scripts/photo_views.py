#!/usr/bin/env python3
"""Other photographs of the Willow outlet, made from the one we have.

The wall in shared/data/willow-2x2/V000.png is a plane whose pose the labels give
(wall_normal, wall_distance_m). A camera elsewhere sees that plane through the
plane-induced homography H = R + t n^T / d; every pixel of a new view is undistorted,
mapped back through H^-1, distorted with the same lens and sampled from V000. Then
gain, gamma, noise and blur vary. Only the wall plane is right (nothing stands out
of it here), so these are fair new views of the outlet, at any distance and angle.

    scripts/photo_views.py OUT COUNT SEED [SCALE [MAX_OFF_AXIS_DEG]]

SCALE resizes the camera (0.5: 784x535, focal 737 px). Writes OUT/vNNN.png,
OUT/camera.yaml, OUT/manifest.jsonl for `outlet detect --batch` (template
`willow.tpl`: train it with `outlet train`), OUT/truth.json (hole pixels in
template order, distance, off-axis angle, roll), and OUT/vNNN.labels.json, so that
`outlet eval --photos OUT --views 0 --template 2x2` judges any template on the views
(found, wrong, and the holes the descriptor classed right).
"""
import json, math, re, sys
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parent.parent.parent / "shared/data/willow-2x2"


def main():
    out = Path(sys.argv[1]); count = int(sys.argv[2]); seed = int(sys.argv[3])
    scale = float(sys.argv[4]) if len(sys.argv) > 4 else 1.0
    max_off_axis = float(sys.argv[5]) if len(sys.argv) > 5 else 45.0
    data = Path(sys.argv[6]) if len(sys.argv) > 6 else DATA
    out.mkdir(parents=True, exist_ok=True)
    img = cv2.imread(str(data / "V000.png"))
    labels = json.loads((data / "V000.labels.json").read_text())
    yaml = (data / "camera.yaml").read_text()
    k = [float(v) for v in re.search(r"camera_matrix:\s*rows: 3\s*cols: 3\s*data: \[(.*?)\]", yaml, re.S).group(1).split(",")]
    dist = np.array([float(v) for v in re.search(r"distortion_coefficients:\s*rows: 1\s*cols: 5\s*data: \[(.*?)\]", yaml, re.S).group(1).split(",")])
    K = np.array(k).reshape(3, 3)
    height, width = img.shape[:2]
    n = np.array(labels["wall_normal"]); d = labels["wall_distance_m"]
    if d < 0:
        n, d = -n, -d
    pixels = np.array([h["pixel"] for h in labels["holes"]], dtype=np.float64)
    rays = np.hstack([cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, dist).reshape(-1, 2), np.ones((len(pixels), 1))])
    holes = rays * (d / (rays @ n))[:, None]  # on the wall, V000's camera frame
    centre = holes.mean(axis=0)

    K2 = K.copy(); K2[0, 0] *= scale; K2[1, 1] *= scale
    K2[0, 2] = (K[0, 2] + 0.5) * scale - 0.5; K2[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    w2, h2 = int(round(width * scale)), int(round(height * scale))
    uu, vv = np.meshgrid(np.arange(w2, dtype=np.float32), np.arange(h2, dtype=np.float32))
    grid = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2), K2, dist).reshape(-1, 2)
    grid = np.hstack([grid, np.ones((len(grid), 1))])
    (out / "camera.yaml").write_text(
        f"image_width: {w2}\nimage_height: {h2}\ncamera_name: willow_view\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{float(K2[0,0])!r}, 0, {float(K2[0,2])!r}, 0, {float(K2[1,1])!r}, {float(K2[1,2])!r}, 0, 0, 1]\n"
        f"distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [{', '.join(repr(float(v)) for v in dist)}]\n")

    rng = np.random.default_rng(seed)
    rows = []
    with open(out / "manifest.jsonl", "w") as manifest:
        for i in range(count):
            distance = rng.uniform(0.2, 0.5)
            off_axis = math.radians(rng.uniform(0, max_off_axis))
            azimuth = rng.uniform(0, 2 * math.pi)
            roll = math.radians(rng.uniform(-15, 15))
            a = np.cross(n, [1.0, 0, 0]); a /= np.linalg.norm(a); b = np.cross(n, a)
            axis = math.cos(azimuth) * a + math.sin(azimuth) * b
            z = cv2.Rodrigues(axis * off_axis)[0] @ n  # looking at the outlet
            position = centre - distance * z
            x = np.cross([0, 1.0, 0], z); x /= np.linalg.norm(x); y = np.cross(z, x)
            R = cv2.Rodrigues(np.array([0, 0, roll]))[0] @ np.stack([x, y, z])
            t = -R @ position
            back = grid @ np.linalg.inv(R + np.outer(t, n) / d).T
            valid = back[:, 2] > 1e-6
            back = back / np.where(valid, back[:, 2], 1.0)[:, None]
            src = cv2.projectPoints(back, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2).astype(np.float32)
            src[~valid] = -1e5
            view = cv2.remap(img, src[:, 0].reshape(h2, w2), src[:, 1].reshape(h2, w2), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            gain, gamma = rng.uniform(0.6, 1.3), rng.uniform(0.7, 1.4)
            f = np.clip(((view / 255.0) ** gamma) * gain, 0, 1) * 255 + rng.normal(0, rng.uniform(0, 4), view.shape)
            view = np.clip(f, 0, 255).astype(np.uint8)
            sigma = rng.uniform(0, 1.2)
            if sigma > 0.3:
                view = cv2.GaussianBlur(view, (0, 0), sigma)
            seen = cv2.projectPoints(holes @ R.T + t, np.zeros(3), np.zeros(3), K2, dist)[0].reshape(-1, 2)
            name = f"v{i:03d}.png"
            cv2.imwrite(str(out / name), view)
            manifest.write(json.dumps({"image": name, "camera": "camera.yaml", "template": "willow.tpl"}) + "\n")
            rows.append({"image": name, "distance_m": distance, "off_axis_deg": math.degrees(off_axis),
                         "roll_deg": math.degrees(roll), "holes": seen.tolist()})
            # The view as a labelled photograph, for `outlet eval --photos OUT --views 0`.
            view_labels = {"image": name, "template": labels.get("template", "2x2"),
                           "holes": [{**h, "pixel": p} for h, p in zip(labels["holes"], seen.tolist())]}
            (out / f"v{i:03d}.labels.json").write_text(json.dumps(view_labels))
    (out / "truth.json").write_text(json.dumps(rows))


if __name__ == "__main__":
    main()
