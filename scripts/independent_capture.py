#!/usr/bin/env python3
"""Render a capture with an independent renderer (Mitsuba 3), for cross-checks.

Every accuracy figure of `svbrdf` measured on our own simulator shares its conventions
and its kindness. This script renders the *same camera path* as a simulator capture
(its ground_truth/truth.json: the flash video's cameras, per-frame focal length and
lens distortion, the reference photo's camera, the markers) but with everything else
made independently of `svbrdf`'s code:

  - the material: glazed square tiles in random colours, a third of them with a
    repeated printed motif, matte grout lines (the repetitive texture issue 18 is
    about), on a grey textured table, with the four ArUco markers drawn by OpenCV
    (python) on white paper;
  - light transport: Mitsuba 3's `direct` integrator, a GGX `roughplastic` glaze over
    the tiles and a Lambertian paper, table and grout, a point light at the flash, a
    constant ambient of about 14% of the flash's diffuse signal (no flash in the
    reference photo: ambient only);
  - the lens: each frame is rendered without distortion at twice the resolution on a
    larger canvas, then resampled through the truth's radial distortion (OpenCV's
    k1, k2, our documented convention, implemented here again in numpy) and
    area-averaged to the frame size;
  - the sensor and encoding: Gaussian read noise, clipping, sRGB encoding, then the
    FFmpeg command line (libx264, BT.709 limited range, tagged) and OpenCV's JPEG for
    the reference photo.

Output: a capture folder (flash.mp4, reference.jpg, camera.json) that `svbrdf align`
reads, and ground_truth/truth.json with the cameras that rendered it, so that
`svbrdf bench --no-brdf --align-capture <registered> --truth <out>` measures the
alignment. Maps are not written: this material is not a Ward BRDF, so only geometry
is checked against the truth.

Needs: python3 -m venv V && V/bin/pip install "mitsuba==3.*" numpy opencv-contrib-python-headless
Usage: V/bin/python scripts/independent_capture.py SIM_CAPTURE OUT [--spp 8] [--seed 1]
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

import cv2
import mitsuba as mi
import numpy as np

# The LLVM variant (needs libLLVM, e.g. Debian's llvm-14, found by DRJIT_LIBLLVM_PATH)
# is several times faster than the scalar one on a CPU.
try:
    mi.set_variant(os.environ.get("XCAP_VARIANT", "llvm_ad_rgb"))
except Exception:  # noqa: BLE001 - no libLLVM: the scalar variant renders the same
    mi.set_variant("scalar_rgb")

# Texels per cm: 60 puts every marker cell edge (0.2 cm), marker corner, paper edge and
# tile edge of the kit's layout on a texel boundary, so the bilinear-filtered edges lie
# exactly where the truth puts them. (At 64 texels per cm the markers came out 0.4%
# small, and every alignment measured against the truth with a 0.4% scale error.)
TEX_PX_PER_CM = 60.0


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def plane_texture(truth, rng):
    """Albedo (linear RGB) and glaze weight over the textured square, row 0 at +y."""
    reg = truth["region"]
    half = max(abs(reg["x_min"]), abs(reg["x_max"]), abs(reg["y_min"]), abs(reg["y_max"]))
    extent = half + 14.0  # cm either side of the centre: markers, paper and table
    n = int(round(2 * extent * TEX_PX_PER_CM))
    # Plane coordinates of pixel centres (x right, y up; row 0 is the largest y).
    xs = -extent + (np.arange(n) + 0.5) / TEX_PX_PER_CM
    ys = extent - (np.arange(n) + 0.5) / TEX_PX_PER_CM
    X, Y = np.meshgrid(xs, ys)
    # Table: grey with low-frequency blotches and fine grain.
    table = 0.18 + 0.05 * np.sin(X * 0.9 + np.sin(Y * 0.7) * 2.0) * np.cos(Y * 1.3)
    grain = rng.normal(0.0, 0.02, size=(n // 8 + 1, n // 8 + 1))
    grain = cv2.resize(grain, (n, n), interpolation=cv2.INTER_CUBIC)
    albedo = np.repeat((table + grain)[..., None], 3, axis=2) * np.array([1.0, 0.95, 0.85])
    glaze = np.zeros((n, n))
    # Tiles: 2.5 cm pitch, 0.25 cm grout, over the region and 1 cm beyond.
    pitch, grout = 2.5, 0.25
    inside = (np.abs(X) <= half + 1.0) & (np.abs(Y) <= half + 1.0)
    ti = np.floor(X / pitch).astype(int)
    tj = np.floor(Y / pitch).astype(int)
    fx = X / pitch - np.floor(X / pitch)
    fy = Y / pitch - np.floor(Y / pitch)
    g = grout / pitch / 2
    is_grout = (fx < g) | (fx > 1 - g) | (fy < g) | (fy > 1 - g)
    palette = srgb_to_linear(
        np.array(
            [
                [0.85, 0.85, 0.82], [0.20, 0.35, 0.60], [0.65, 0.15, 0.15], [0.15, 0.50, 0.35],
                [0.90, 0.75, 0.30], [0.35, 0.35, 0.38], [0.55, 0.70, 0.80], [0.95, 0.95, 0.95],
            ]
        )
    )
    k = int(math.ceil((half + 1.0) / pitch)) + 1
    colours = rng.integers(0, len(palette), size=(2 * k + 1, 2 * k + 1))
    motif = rng.random((2 * k + 1, 2 * k + 1)) < 0.33
    ci = np.clip(ti + k, 0, 2 * k)
    cj = np.clip(tj + k, 0, 2 * k)
    tile_rgb = palette[colours[cj, ci]]
    # The printed motif: a diamond and a ring, the same on every motif tile.
    u, v = fx - 0.5, fy - 0.5
    ring = np.abs(np.hypot(u, v) - 0.28) < 0.035
    diamond = (np.abs(u) + np.abs(v)) < 0.12
    printed = motif[cj, ci] & (ring | diamond)
    tile_rgb = np.where(printed[..., None], tile_rgb * 0.35, tile_rgb)
    tile = inside & ~is_grout
    albedo = np.where(tile[..., None], tile_rgb, albedo)
    grout_rgb = srgb_to_linear([0.62, 0.60, 0.56])
    albedo = np.where((inside & is_grout)[..., None], grout_rgb, albedo)
    glaze = np.where(tile, 1.0, 0.0)
    # Markers on white paper, drawn by OpenCV's own ArUco module.
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    margin = truth["config"]["markers"]["paper_margin_cm"]
    for m in truth["markers"]:
        c = np.array(m["corners_cm"])[:, :2]
        x0, x1 = c[:, 0].min(), c[:, 0].max()
        y0, y1 = c[:, 1].min(), c[:, 1].max()
        paper = (X >= x0 - margin) & (X <= x1 + margin) & (Y >= y0 - margin) & (Y <= y1 + margin)
        albedo[paper] = srgb_to_linear([0.92, 0.92, 0.90])
        glaze[paper] = 0.0
        cells = 8  # 6x6 bits and a one-cell border
        img = cv2.aruco.generateImageMarker(dictionary, m["id"], cells)
        sel = (X >= x0) & (X < x1) & (Y > y0) & (Y <= y1)
        col = np.clip(((X[sel] - x0) / (x1 - x0) * cells).astype(int), 0, cells - 1)
        row = np.clip(((y1 - Y[sel]) / (y1 - y0) * cells).astype(int), 0, cells - 1)
        ink = img[row, col] < 128
        vals = np.where(ink[:, None], srgb_to_linear([0.03, 0.03, 0.03]), srgb_to_linear([0.92, 0.92, 0.90]))
        albedo[sel] = vals
    return np.clip(albedo, 0.0, 1.0), glaze, extent


def scene_dict(albedo, glaze, extent):
    # Mitsuba's rectangle has v = 0 at y = -1 and its bitmaps put v = 0 on their first
    # row: hand them the maps bottom row first (checked: the markers then decode, with
    # their ids where the truth puts them).
    rgb = mi.Bitmap(np.ascontiguousarray(albedo[::-1]).astype(np.float32), pixel_format=mi.Bitmap.PixelFormat.RGB)
    w = mi.Bitmap(np.ascontiguousarray(glaze[::-1, :, None]).astype(np.float32), pixel_format=mi.Bitmap.PixelFormat.Y)
    tex = {"type": "bitmap", "bitmap": rgb, "raw": True, "filter_type": "bilinear"}
    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1},
        "plane": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f().scale([extent, extent, 1.0]),
            "bsdf": {
                "type": "blendbsdf",
                "weight": {"type": "bitmap", "bitmap": w, "raw": True, "filter_type": "bilinear"},
                "bsdf_0": {"type": "diffuse", "reflectance": tex},
                "bsdf_1": {
                    "type": "roughplastic",
                    "distribution": "ggx",
                    "alpha": 0.06,
                    "int_ior": 1.5,
                    "diffuse_reflectance": tex,
                },
            },
        },
    }


def sensor(cam, scale, pad):
    """A Mitsuba camera for a truth camera (OpenCV axes), undistorted, on a canvas
    `pad` times larger and `scale` times finer."""
    intr = cam["intrinsics"]
    w = int(round(intr["width"] * pad * scale))
    h = int(round(intr["height"] * pad * scale))
    fx = intr["fx"] * scale
    fov = math.degrees(2 * math.atan((w / 2) / fx))
    R = np.array(cam["rotation"])  # world_from_camera, OpenCV camera axes
    C = np.array(cam["position"])
    fwd, down = R[:, 2], R[:, 1]
    to_world = mi.ScalarTransform4f().look_at(
        origin=mi.ScalarPoint3f(*C), target=mi.ScalarPoint3f(*(C + fwd)), up=mi.ScalarVector3f(*(-down))
    )
    return {
        "type": "perspective",
        "fov": fov,
        "fov_axis": "x",
        "near_clip": 0.5,
        "far_clip": 1000.0,
        "to_world": to_world,
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "gaussian"}, "pixel_format": "rgb"},
    }, (w, h, fx)


def undistort_norm(xd, yd, k1, k2):
    """Undistorted normalised coordinates of distorted ones (Newton on the radius)."""
    rd = np.hypot(xd, yd)
    ru = rd.copy()
    for _ in range(8):
        f = ru * (1 + k1 * ru**2 + k2 * ru**4) - rd
        df = 1 + 3 * k1 * ru**2 + 5 * k2 * ru**4
        ru = ru - f / df
    s = np.where(rd > 0, ru / np.maximum(rd, 1e-12), 1.0)
    return xd * s, yd * s


def render_camera(scene, cam, spp, seed, lights, ambient, scale=2, pad=1.08):
    intr = cam["intrinsics"]
    sdict, (w, h, fxs) = sensor(cam, scale, pad)
    s = mi.load_dict(sdict)
    sc = mi.load_dict({**scene, **lights, "ambient": {"type": "constant", "radiance": {"type": "rgb", "value": ambient}}})
    img = np.array(mi.render(sc, sensor=s, spp=spp, seed=seed))[..., :3]
    # Resample through the lens: for each pixel of a 2x distorted grid, its undistorted
    # position on the padded canvas.
    W, H = intr["width"], intr["height"]
    jj, ii = np.meshgrid(np.arange(H * scale), np.arange(W * scale), indexing="ij")
    # Centres of the fine grid's pixels in frame pixel units (OpenCV centres).
    u = (ii + 0.5) / scale - 0.5
    v = (jj + 0.5) / scale - 0.5
    xd = (u - intr["cx"]) / intr["fx"]
    yd = (v - intr["cy"]) / intr["fy"]
    k1, k2 = cam["distortion"]["k1"], cam["distortion"]["k2"]
    xu, yu = undistort_norm(xd, yd, k1, k2)
    # Canvas pixel centres: the principal point is the canvas centre.
    map_x = (xu * fxs + (w - 1) / 2).astype(np.float32)
    map_y = (yu * intr["fy"] * scale + (h - 1) / 2).astype(np.float32)
    fine = cv2.remap(img.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return cv2.resize(fine, (W, H), interpolation=cv2.INTER_AREA)


def to_8bit(linear, rng, read_noise=0.002):
    noisy = linear + rng.normal(0.0, read_noise, size=linear.shape)
    return np.round(linear_to_srgb(noisy) * 255).astype(np.uint8)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sim_capture", help="a simulator capture folder (its ground_truth/truth.json gives the cameras)")
    ap.add_argument("out", help="the capture folder to write (must not exist)")
    ap.add_argument("--spp", type=int, default=4, help="samples per fine pixel (4 fine pixels per frame pixel)")
    ap.add_argument("--seed", type=int, default=1, help="the material's and the noise's seed")
    ap.add_argument("--frames", type=int, default=0, help="render only the first N frames (0: all)")
    args = ap.parse_args()
    if os.path.exists(args.out):
        sys.exit(f"{args.out} exists; give a new folder")
    with open(os.path.join(args.sim_capture, "ground_truth", "truth.json")) as f:
        truth = json.load(f)
    rng = np.random.default_rng(args.seed)
    albedo, glaze, extent = plane_texture(truth, rng)
    scene = scene_dict(albedo, glaze, extent)
    flash_i = float(truth["config"]["light"]["flash_intensity"])
    # Ambient radiance: about 14% of the flash's diffuse signal at 11 cm.
    ambient = 0.14 * flash_i / 11.0**2
    os.makedirs(os.path.join(args.out, "ground_truth"))
    stream = truth["streams"][0]
    frames = stream["frames"][: args.frames] if args.frames else stream["frames"]
    tmp = tempfile.mkdtemp(prefix="xcap-")
    try:
        for k, fr in enumerate(frames):
            lights = {"flash": {"type": "point", "position": fr["light_position"], "intensity": {"type": "rgb", "value": flash_i}}}
            lin = render_camera(scene, fr["camera"], args.spp, args.seed * 100003 + k, lights, ambient)
            cv2.imwrite(os.path.join(tmp, f"f{k:04d}.png"), cv2.cvtColor(to_8bit(lin, rng), cv2.COLOR_RGB2BGR))
            fr["motion_blur"] = False
            fr["exposure_gain"] = 1.0
            fr["first_lit_row"] = None
            print(f"frame {k + 1}/{len(frames)}", file=sys.stderr, flush=True)
        fps = stream["fps"]
        subprocess.run(
            [
                "ffmpeg", "-loglevel", "error", "-y", "-framerate", str(fps), "-i", os.path.join(tmp, "f%04d.png"),
                "-vf", "scale=out_color_matrix=bt709:out_range=tv,format=yuv420p",
                "-c:v", "libx264", "-crf", "18", "-preset", "medium",
                "-color_range", "tv", "-colorspace", "bt709", "-color_primaries", "bt709", "-color_trc", "bt709",
                os.path.join(args.out, "flash.mp4"),
            ],
            check=True,
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    # The reference photo: no flash, the room's light only (brighter, as a photo's
    # exposure would make it).
    ref = truth["reference"]
    lin = render_camera(scene, ref["camera"], max(args.spp, 4), args.seed * 7, {}, 0.9)
    cv2.imwrite(os.path.join(args.out, "reference.jpg"), cv2.cvtColor(to_8bit(lin, rng), cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_JPEG_QUALITY, 92])
    shutil.copy(os.path.join(args.sim_capture, "camera.json"), os.path.join(args.out, "camera.json"))
    stream["frames"] = frames
    # truth.json keeps the simulator's schema (its config still names the simulator's
    # material, which was not rendered); what was rendered is in independent.json.
    with open(os.path.join(args.out, "ground_truth", "independent.json"), "w") as f:
        json.dump({"renderer": "mitsuba " + mi.__version__ + " " + mi.variant() + " direct", "material":
                   "glazed tiles 2.5 cm, grout 0.25 cm, roughplastic ggx alpha 0.06", "seed": args.seed,
                   "spp": args.spp, "from": os.path.abspath(args.sim_capture)}, f, indent=1)
    with open(os.path.join(args.out, "ground_truth", "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    print(f"wrote {args.out}: {len(frames)} frames, reference photo, truth", file=sys.stderr)


if __name__ == "__main__":
    main()
