#!/usr/bin/env python3
"""Cut a small real-data evaluation set out of a BOP dataset (e.g. YCB-Video or LM-O test frames committed in
a public repository): a few images of one scene, their ground truth, and decimated models of the objects in
them, in BOP layout, with a SOURCE.md saying where every byte came from.

The source is a folder, or a git directory without a work tree (what the project's `fetch` tool brings:
files are read with `git show COMMIT:PATH`). Images are chosen where every `--dishware` object is at least
`--min-visib` visible, spread evenly over the scene; with world camera poses in scene_camera.json
(YCB-Video's BOP test scenes have them) the images form one multi-view scan for `kitchenbot eval`.

    python scripts/extract_real_frames.py SOURCE --path ycbv --scene 48 --dishware 13 14 \\
        --name 13=024_bowl:bowl --name 14=025_mug:mug --images 3 --out tests/data/real/ycbv_48 \\
        --repo OWNER/NAME --licence "CC BY 4.0 (YCB-Video, via BOP)"

Then: `kitchenbot eval tests/data/real/ycbv_48 --objects 13 14 --cell never`.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import open3d as o3d
from PIL import Image


class Source:
    """Files of a dataset in a folder or in a git directory at a commit."""

    def __init__(self, root: Path, path: str, commit: str | None):
        self.root, self.path = Path(root), path.strip("/")
        self.git = (self.root / "HEAD").is_file() and (self.root / "objects").is_dir()
        self.commit = commit
        if self.git and commit is None:
            self.commit = subprocess.run(["git", "--git-dir", str(self.root), "rev-parse", "HEAD"], check=True,
                                         capture_output=True, text=True).stdout.strip()

    def _rel(self, rel: str) -> str:
        return f"{self.path}/{rel}" if self.path else rel

    def read(self, rel: str) -> bytes:
        if self.git:
            r = subprocess.run(["git", "--git-dir", str(self.root), "show", f"{self.commit}:{self._rel(rel)}"],
                               capture_output=True)
            if r.returncode != 0:
                raise FileNotFoundError(f"{self.root}@{self.commit}: no {self._rel(rel)}")
            return r.stdout
        p = self.root / self._rel(rel)
        if not p.is_file():
            raise FileNotFoundError(f"{p}: missing")
        return p.read_bytes()

    def json(self, rel: str):
        return json.loads(self.read(rel))

    def exists(self, rel: str) -> bool:
        try:
            self.read(rel)
            return True
        except FileNotFoundError:
            return False


def choose_images(gt: dict, info: dict, dishware: list[int], n: int, min_visib: float) -> list[int]:
    """`n` image ids where every dishware object is at least `min_visib` visible, evenly spread."""
    ok = []
    for key in sorted(gt, key=int):
        vis = {}
        for rec, inf in zip(gt[key], info.get(key, [{}] * len(gt[key]))):
            vis[rec["obj_id"]] = max(vis.get(rec["obj_id"], 0.0), inf.get("visib_fract", 1.0))
        if all(vis.get(o, 0.0) >= min_visib for o in dishware):
            ok.append(int(key))
    if len(ok) < n:
        raise SystemExit(f"only {len(ok)} images show all of {dishware} at least {min_visib:.0%} visible "
                         f"(need {n}); lower --min-visib or --images")
    idx = np.round(np.linspace(0, len(ok) - 1, n)).astype(int)
    return [ok[i] for i in idx]


def decimate_ply(data: bytes, triangles: int) -> o3d.geometry.TriangleMesh:
    """A BOP model (PLY, mm) reduced to about `triangles` faces (quadric decimation), normals and colours kept."""
    with tempfile.TemporaryDirectory() as d:  # Open3D reads meshes from files only
        tmp = Path(d) / "model.ply"
        tmp.write_bytes(data)
        mesh = o3d.io.read_triangle_mesh(str(tmp))
    if len(mesh.triangles) == 0:
        raise SystemExit("a model has no faces (a point cloud PLY?)")
    if len(mesh.triangles) > triangles:
        mesh = mesh.simplify_quadric_decimation(triangles)
    mesh.remove_unreferenced_vertices()
    mesh.compute_vertex_normals()
    return mesh


def _find(src: Source, scene: str, sub: tuple[str, ...], im_id: int) -> tuple[str, bytes]:
    for s in sub:
        for ext in (".png", ".jpg", ".tif"):
            rel = f"{scene}/{s}/{im_id:06d}{ext}"
            try:
                return rel, src.read(rel)
            except FileNotFoundError:
                continue
    raise SystemExit(f"no {'/'.join(sub)} image {im_id:06d} in {scene} (this source has no such frames; a set "
                     f"without depth cannot be used: the pipeline needs RGB-D)")


def extract(args: argparse.Namespace) -> dict:
    src = Source(args.source, args.path, args.commit)
    scene = f"{args.split}/{args.scene:06d}"
    cams = src.json(f"{scene}/scene_camera.json")
    gt = src.json(f"{scene}/scene_gt.json")
    info = src.json(f"{scene}/scene_gt_info.json") if src.exists(f"{scene}/scene_gt_info.json") else {}
    ims = args.image_ids or choose_images(gt, info, args.dishware, args.images, args.min_visib)
    out = Path(args.out)
    sd = out / "test" / f"{args.scene:06d}"
    for sub in ("rgb", "depth"):
        (sd / sub).mkdir(parents=True, exist_ok=True)
    files = []
    for im in ims:
        for sub, dst in ((("rgb", "gray"), "rgb"), (("depth",), "depth")):
            rel, data = _find(src, scene, sub, im)
            if dst == "rgb" and args.jpeg:  # smaller; BOP readers take .jpg
                img = Image.open(io.BytesIO(data)).convert("RGB")
                img.save(sd / "rgb" / f"{im:06d}.jpg", quality=args.jpeg)
            else:
                (sd / dst / f"{im:06d}{Path(rel).suffix}").write_bytes(data)
            files.append(src._rel(rel))
        if args.masks:
            for k in range(len(gt[str(im)])):
                rel = f"{scene}/mask_visib/{im:06d}_{k:06d}.png"
                if src.exists(rel):
                    (sd / "mask_visib").mkdir(exist_ok=True)
                    (sd / "mask_visib" / f"{im:06d}_{k:06d}.png").write_bytes(src.read(rel))
                    files.append(src._rel(rel))
    keep = {str(i) for i in ims}
    (sd / "scene_camera.json").write_text(json.dumps({k: v for k, v in cams.items() if k in keep}, indent=1))
    (sd / "scene_gt.json").write_text(json.dumps({k: v for k, v in gt.items() if k in keep}, indent=1))
    if info:
        (sd / "scene_gt_info.json").write_text(json.dumps({k: v for k, v in info.items() if k in keep}, indent=1))
    # Models of every object in the chosen images: dishware finer, the rest coarser.
    ids = sorted({rec["obj_id"] for k in keep for rec in gt[k]})
    minfo = src.json(f"{args.models}/models_info.json")
    md = out / "models"
    md.mkdir(parents=True, exist_ok=True)
    names = dict(_parse_name(s) for s in args.name)
    objects, new_info = {}, {}
    for oid in ids:
        tri = args.dishware_triangles if oid in args.dishware else args.other_triangles
        mesh = decimate_ply(src.read(f"{args.models}/obj_{oid:06d}.ply"), tri)
        o3d.io.write_triangle_mesh(str(md / f"obj_{oid:06d}.ply"), mesh, write_ascii=False)
        new_info[str(oid)] = minfo[str(oid)]
        name, cls = names.get(oid, (f"obj_{oid:06d}", "dishware" if oid in args.dishware else "distractor"))
        objects[str(oid)] = {"name": name, "class": cls, "grasps": []}
        files.append(src._rel(f"{args.models}/obj_{oid:06d}.ply"))
    (md / "models_info.json").write_text(json.dumps(new_info, indent=1))
    (md / "grasps.json").write_text(json.dumps({"units": "m", "objects": objects}, indent=1))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    repo = args.repo or str(args.source)
    cmd = " ".join(["python", "scripts/extract_real_frames.py", *sys.argv[1:]])
    (out / "SOURCE.md").write_text(f"""# Source of this evaluation set

- repository: {repo}
- commit: {src.commit or "(a plain folder, no commit)"}
- path in the repository: {args.path or "."} (split `{args.split}`, scene {args.scene}, models `{args.models}`)
- images: {", ".join(str(i) for i in ims)} (rgb, depth{", mask_visib" if args.masks else ""}), ground truth of those
  images only; models decimated to ~{args.dishware_triangles} (dishware) / ~{args.other_triangles} (others) faces
- licence: {args.licence}
- extracted {datetime.now(timezone.utc):%Y-%m-%d} with
  `{cmd}`
- dishware to find (`kitchenbot eval --objects`): {", ".join(str(d) for d in args.dishware)}; every other object
  in the ground truth is a distractor that must get no pose
- size: {size / 1e6:.2f} MB

Files read from the source (paths in the repository):

{chr(10).join(f"- `{f}`" for f in files)}
""")
    return {"images": ims, "objects": ids, "bytes": size, "commit": src.commit}


def _parse_name(text: str) -> tuple[int, tuple[str, str]]:
    try:
        oid, rest = text.split("=", 1)
        name, cls = rest.split(":", 1)
        return int(oid), (name, cls)
    except ValueError:
        raise SystemExit(f"--name {text!r}: expected ID=NAME:CLASS, e.g. 13=024_bowl:bowl") from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="dataset folder, or a git directory (e.g. /work/.mirror/o+n/repo)")
    p.add_argument("--path", default="", help="the dataset's folder inside the source (default: its root)")
    p.add_argument("--commit", help="git commit to read (default: HEAD)")
    p.add_argument("--split", default="test")
    p.add_argument("--models", default="models", help="models folder inside the dataset (default: models)")
    p.add_argument("--scene", type=int, required=True)
    p.add_argument("--dishware", type=int, nargs="+", required=True, help="obj ids that are the inventory")
    p.add_argument("--name", action="append", default=[], help="ID=NAME:CLASS, e.g. 13=024_bowl:bowl")
    p.add_argument("--images", type=int, default=3, help="how many images (default 3)")
    p.add_argument("--image-ids", type=int, nargs="+", help="exactly these image ids instead")
    p.add_argument("--min-visib", type=float, default=0.5)
    p.add_argument("--masks", action="store_true", help="copy mask_visib too")
    p.add_argument("--jpeg", type=int, metavar="QUALITY", help="store rgb as JPEG of this quality (smaller)")
    p.add_argument("--dishware-triangles", type=int, default=4000)
    p.add_argument("--other-triangles", type=int, default=1000)
    p.add_argument("--repo", help="OWNER/NAME of the source repository, for SOURCE.md")
    p.add_argument("--licence", default="see the source repository", help="licence of the frames, for SOURCE.md")
    p.add_argument("--out", required=True, type=Path)
    args = p.parse_args(argv)
    r = extract(args)
    print(f"wrote {len(r['images'])} images ({r['images']}), {len(r['objects'])} models, "
          f"{r['bytes'] / 1e6:.2f} MB to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
