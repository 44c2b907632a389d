#!/usr/bin/python3
"""Converts binpick depth frames into point clouds written by other tools.

For each 16-bit depth PNG given (binpick render's depth.png, or any
<stem>depth.png with its <stem>depth.intrinsics.json), the points are
deprojected by Open3D (create_from_depth_image: x = (u - cx) z / fx, in
double) and written by the chosen writer into OUT as <name>_cloud.<ext>, with
a sidecar <name>_cloud.intrinsics.json (X_BC only: an unorganized cloud) and
the frame's truth as <name>_truth.json, so that

    binpick eval --source files:OUT

scores the clouds (docs/file_formats.md), and with --depth-out DIR2, `binpick
eval --source files:DIR2` their depth images. <name> is --name, else the
frame's directory name (binpick render --out DIR) or its stem.

Writers (--writer):
  open3d-ply        Open3D's default PLY: binary, property double x y z
  open3d-ply-extras Open3D PLY with normals (double) and colours (uchar)
  open3d-pcd        Open3D's PCD: binary float32, VIEWPOINT identity
  pcl-compressed    PCL's writer (pcl_converter, pcl-tools): binary_compressed
                    PCD of the Open3D cloud with normals and rgb
  pcl-ascii         PCL's writer: ascii PCD, x y z and normals
  hand-ascii-mm     an ascii PCD written here line by line: comments, CRLF line
                    ends, x y z intensity in millimetres, "unit": "mm" in the
                    sidecar
  organized-viewpoint  an organized binary PCD written here: width x height
                    with NaN holes, the points in the bin frame W and the
                    camera in VIEWPOINT, no intrinsics in the sidecar (X_BC
                    there is the bin's pose X_BW)

--frame rotated:DEG writes the points in a frame F turned DEG about the
camera's x then y axes (X_BF in the sidecar): the cloud of a vendor tool that
reports its own frame, no longer on the camera's pixel lattice. --merge DIR2
adds the points of a second rendering of the same pile (same seed, another
camera: binpick render --cell ...) moved into the first camera's frame: a
cloud merged from two cameras. --crop bin keeps the points inside the bin's
inner box, as viewers export a region of interest; --crop half only those
with x >= 0 in the bin frame (smaller files), and the truth's visible_pixels
and visible_fraction are then counted over the kept points (the frame's
labels.png), so that recall counts the parts half visible in the crop.

Needs Debian's python3-open3d and python3-numpy; pcl-tools for the
pcl-* writers. Run with /usr/bin/python3.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
import open3d as o3d


def read_frame(depth_png):
    stem, _ = os.path.splitext(depth_png)
    with open(stem + ".intrinsics.json") as f:
        side = json.load(f)
    counts = np.asarray(o3d.io.read_image(depth_png))
    if counts.dtype != np.uint16 or counts.ndim != 2:
        sys.exit(f"{depth_png}: not a 16-bit PNG")
    scale = side.get("depth_scale", 0.0001)
    intr = o3d.camera.PinholeCameraIntrinsic(side["width"], side["height"], side["fx"], side["fy"], side["cx"],
                                             side["cy"])
    cloud = o3d.geometry.PointCloud.create_from_depth_image(o3d.geometry.Image(counts), intr,
                                                            depth_scale=1.0 / scale, depth_trunc=1e9)
    d = os.path.dirname(depth_png)
    base = os.path.basename(stem)
    truth = os.path.join(d, base[:-5] + "truth.json") if base.endswith("depth") else stem + ".truth.json"
    intensity = os.path.join(d, base[:-5] + "intensity.png") if base.endswith("depth") else None
    return {
        "cloud": cloud,
        "counts": counts,
        "scale": scale,
        "side": side,
        "X_BC": np.array(side["X_BC"], dtype=float),
        "truth": truth,
        "intensity": intensity if intensity and os.path.exists(intensity) else None,
    }


def rot_xy(deg):
    a = math.radians(deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    return ry @ rx


def rigid(R, t):
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = t
    return X


def add_colours(cloud, frame):
    """Grey colours from the intensity image (valid pixels in row order, as Open3D deprojects)."""
    if frame["intensity"] is None:
        grey = np.full(len(cloud.points), 0.5)
    else:
        img = np.asarray(o3d.io.read_image(frame["intensity"]))
        grey = img[frame["counts"] > 0].astype(float) / 255.0
    cloud.colors = o3d.utility.Vector3dVector(np.repeat(grey[:, None], 3, axis=1))


def crop_mask(points_C, X_BC, X_BW, args):
    """Points inside the bin's inner box (x >= 0 in W too for --crop half)."""
    X_WC = np.linalg.inv(X_BW) @ X_BC
    p_W = points_C @ X_WC[:3, :3].T + X_WC[:3, 3]
    half = np.array(args.bin_size) / 2
    keep = (np.abs(p_W[:, 0]) <= half[0]) & (np.abs(p_W[:, 1]) <= half[1]) & (p_W[:, 2] <= args.bin_size[2])
    if args.crop == "half":
        keep &= p_W[:, 0] >= 0.0
    return keep


def recount_visibility(truth, frame, keep_pixels):
    """visible_pixels / visible_fraction of each part over the kept pixels (labels.png)."""
    labels_path = frame["truth"].replace("truth.json", "labels.png")
    labels = np.asarray(o3d.io.read_image(labels_path))[frame["counts"] > 0]
    kept = labels[keep_pixels]
    for part in truth["parts"]:
        n = int(np.count_nonzero(kept == part["instance_id"]))
        part["visible_pixels"] = n
        total = part.get("unoccluded_pixels", 0)
        part["visible_fraction"] = n / total if total > 0 else 0.0
    truth["source"] = truth.get("source", "") + " (cropped to x >= 0 in the bin frame)"


def write_depth_reference(out_dir, name, frame, keep_pixels, truth):
    """The frame's depth PNG with the same crop, its sidecar and truth: what the cloud is scored against."""
    counts = frame["counts"].copy()
    if keep_pixels is not None:
        valid = counts > 0
        cropped = np.zeros_like(valid)
        cropped[valid] = keep_pixels
        counts[~cropped] = 0
    o3d.io.write_image(os.path.join(out_dir, name + "_depth.png"), o3d.geometry.Image(counts))
    side = dict(frame["side"])
    with open(os.path.join(out_dir, name + "_depth.intrinsics.json"), "w") as f:
        json.dump(side, f, indent=2)
        f.write("\n")
    with open(os.path.join(out_dir, name + "_truth.json"), "w") as f:
        json.dump(truth, f, indent=2)
        f.write("\n")


def write_sidecar(path, X_BC, extra=None):
    side = {"format": "binpick.intrinsics/1", "X_BC": X_BC.tolist()}
    side.update(extra or {})
    with open(path, "w") as f:
        json.dump(side, f, indent=2)
        f.write("\n")


def write_hand_ascii_mm(path, pts):
    with open(path, "w", newline="") as f:
        f.write("# .PCD v0.7 - Point Cloud Data file format\r\n# written by hand: millimetres, intensity\r\n")
        f.write("VERSION 0.7\r\nFIELDS x y z intensity\r\nSIZE 4 4 4 4\r\nTYPE F F F F\r\nCOUNT 1 1 1 1\r\n")
        f.write(f"WIDTH {len(pts)}\r\nHEIGHT 1\r\nVIEWPOINT 0 0 0 1 0 0 0\r\nPOINTS {len(pts)}\r\nDATA ascii\r\n")
        for p in pts:
            mm = p * 1000.0
            f.write(f"{mm[0]:.3f} {mm[1]:.3f} {mm[2]:.3f} {int(abs(mm[2])) % 256}\r\n")


def write_organized_viewpoint(path, frame, X_BW, keep_pixels=None):
    """Organized W x H binary PCD in the bin frame W, NaN for no point, VIEWPOINT = the camera in W."""
    side = frame["side"]
    w, h = side["width"], side["height"]
    z = frame["counts"].astype(np.float64) * frame["scale"]
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    p_C = np.stack([(u - side["cx"]) / side["fx"] * z, (v - side["cy"]) / side["fy"] * z, z], axis=-1)
    X_WC = np.linalg.inv(X_BW) @ frame["X_BC"]
    p_W = p_C @ X_WC[:3, :3].T + X_WC[:3, 3]
    valid = frame["counts"] > 0
    if keep_pixels is not None:
        cropped = np.zeros_like(valid)
        cropped[valid] = keep_pixels
        valid = cropped
    p_W[~valid] = np.nan
    q = quat_wxyz(X_WC[:3, :3])
    t = X_WC[:3, 3]
    header = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
              f"COUNT 1 1 1\nWIDTH {w}\nHEIGHT {h}\n"
              f"VIEWPOINT {t[0]:.9g} {t[1]:.9g} {t[2]:.9g} {q[0]:.9g} {q[1]:.9g} {q[2]:.9g} {q[3]:.9g}\n"
              f"POINTS {w * h}\nDATA binary\n")
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(p_W.astype("<f4").tobytes())


def quat_wxyz(R):
    w = math.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return (w / n, x / n, y / n, z / n)


def convert(depth_png, out_dir, args):
    frame = read_frame(depth_png)
    name = args.name or os.path.basename(os.path.dirname(os.path.abspath(depth_png)))
    if args.name is None and os.path.basename(depth_png) != "depth.png":
        name = os.path.basename(os.path.splitext(depth_png)[0])
        name = name[:-6] if name.endswith("_depth") else name
    cloud = frame["cloud"]
    if args.writer in ("open3d-ply-extras", "pcl-compressed"):
        add_colours(cloud, frame)  # before a merge or a crop: one colour per valid pixel
    X_BC = frame["X_BC"]
    X_BW = rigid(np.eye(3), np.array(args.bin_xyz, dtype=float))
    if args.merge:
        other = read_frame(os.path.join(args.merge, "depth.png") if os.path.isdir(args.merge) else args.merge)
        X_CC2 = np.linalg.inv(X_BC) @ other["X_BC"]
        cloud = cloud + o3d.geometry.PointCloud(other["cloud"]).transform(X_CC2)
    truth = json.load(open(frame["truth"]))
    keep_pixels = None  # crop of the first camera's valid pixels, in row order
    if args.crop != "none":
        keep = crop_mask(np.asarray(cloud.points), X_BC, X_BW, args)
        n1 = len(frame["cloud"].points)
        keep_pixels = keep[:n1]
        cloud = cloud.select_by_index(np.nonzero(keep)[0])
        if args.crop == "half":
            recount_visibility(truth, frame, keep_pixels)
    X_BF = X_BC
    if args.frame.startswith("rotated:"):
        R_CF = rot_xy(float(args.frame.split(":")[1]))
        X_CF = rigid(R_CF, [0.01, -0.02, 0.005])
        cloud.transform(np.linalg.inv(X_CF))
        X_BF = X_BC @ X_CF
    stem = os.path.join(out_dir, name + "_cloud")
    side_extra = {}
    w = args.writer
    if w in ("open3d-ply", "open3d-ply-extras"):
        if w == "open3d-ply-extras":
            cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.006, max_nn=16))
        o3d.io.write_point_cloud(stem + ".ply", cloud)
    elif w == "open3d-pcd":
        o3d.io.write_point_cloud(stem + ".pcd", cloud)
    elif w in ("pcl-compressed", "pcl-ascii"):
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.006, max_nn=16))
        with tempfile.TemporaryDirectory() as tmp:
            src = os.path.join(tmp, "in.ply")
            o3d.io.write_point_cloud(src, cloud)
            fmt = "binary_compressed" if w == "pcl-compressed" else "ascii"
            subprocess.run(["pcl_converter", "-f", fmt, src, stem + ".pcd"], check=True, stdout=subprocess.DEVNULL)
    elif w == "hand-ascii-mm":
        write_hand_ascii_mm(stem + ".pcd", np.asarray(cloud.points))
        side_extra["unit"] = "mm"
    elif w == "organized-viewpoint":
        write_organized_viewpoint(stem + ".pcd", frame, X_BW, keep_pixels)
        X_BF = X_BW
    else:
        sys.exit(f"unknown writer {w}")
    write_sidecar(stem + ".intrinsics.json", X_BF, side_extra)
    with open(os.path.join(out_dir, name + "_truth.json"), "w") as f:
        json.dump(truth, f, indent=2)
        f.write("\n")
    if args.depth_out:
        os.makedirs(args.depth_out, exist_ok=True)
        write_depth_reference(args.depth_out, name, frame, keep_pixels, truth)
    print(f"{depth_png} -> {stem} ({w}, {len(cloud.points)} points)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("depth_png", nargs="+", help="depth PNG files or binpick render directories")
    ap.add_argument("--out", required=True)
    ap.add_argument("--writer", default="open3d-ply")
    ap.add_argument("--frame", default="camera", help="camera | rotated:DEG")
    ap.add_argument("--merge", help="a second rendering of the same pile (directory or depth PNG)")
    ap.add_argument("--crop", choices=["none", "bin", "half"], default="none")
    ap.add_argument("--bin-xyz", type=float, nargs=3, default=[0.7, 0.0, 0.0], help="X_BW translation (rpy 0)")
    ap.add_argument("--bin-size", type=float, nargs=3, default=[0.5, 0.36, 0.2], help="bin inner size, m")
    ap.add_argument("--name", help="output name (one input only)")
    ap.add_argument("--depth-out", help="also write the first camera's depth PNG, cropped alike, with the same "
                    "truth, as <name>_depth.png here (the reference the cloud is scored against)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    for p in args.depth_png:
        convert(os.path.join(p, "depth.png") if os.path.isdir(p) else p, args.out, args)


if __name__ == "__main__":
    main()
