"""Write a synthetic dataset in the nuScenes format that the unmodified devkit loads.

Layout under ``outdir``::

    <version>/{category,attribute,visibility,instance,sensor,calibrated_sensor,
               ego_pose,log,scene,sample,sample_data,sample_annotation,map}.json
    maps/<token>.png                          # base map mask per location: road + sidewalks (lightemma.synth.maps)
    maps/expansion/<location>.json            # map expansion: drivable area, lanes, road segments (lightemma.synth.maps)
    can_bus/<scene>_pose.json                 # CAN-bus-like pose messages at 50 Hz (lightemma.synth.can_pose)
    samples/CAM_FRONT/<log>__CAM_FRONT__<µs>.jpg   # keyframes, 2 Hz
    sweeps/CAM_FRONT/<log>__CAM_FRONT__<µs>.jpg    # sweeps, 12 Hz between keyframes
    lightemma-synth.json                      # what was generated (seed, scenes, parameters)

Every table and image is written atomically (temporary file + rename), and
the whole output is a pure function of the arguments. Files outside ``<version>/`` are shared by every version
written into the root: the writer refuses, before writing anything, when one exists with other bytes.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from lightemma.errors import UserError
from lightemma.frames.model import SYNTH_MARKER
from lightemma.nuscenes.json_tables import TABLES
from lightemma.synth import can_pose as synth_can
from lightemma.synth import maps as synth_maps
from lightemma.synth.camera import Camera
from lightemma.synth.drawing import render_frame
from lightemma.synth.situations import Scenario, sweep_times_us

GENERATOR = "lightemma-synth/1"
CHANNEL = "CAM_FRONT"
CATEGORIES = (
    ("vehicle.car", "Vehicle designed primarily for personal use, e.g. sedans, hatch-backs, wagons, vans, SUVs."),
    (
        "vehicle.truck",
        "Vehicles primarily designed to haul cargo including pick-ups, lorries, trucks and semi-tractors.",
    ),
    ("human.pedestrian.adult", "Adult subcategory."),
)
ATTRIBUTES = (
    ("vehicle.moving", "Vehicle is moving."),
    ("vehicle.stopped", "Vehicle, with a driver/rider in/on it, is currently stationary but has an intent to move."),
    ("vehicle.parked", "Vehicle is stationary (usually for longer duration) with no immediate intent to move."),
)
VISIBILITIES = (
    ("1", "v0-40", "visibility of whole object is between 0 and 40%"),
    ("2", "v40-60", "visibility of whole object is between 40 and 60%"),
    ("3", "v60-80", "visibility of whole object is between 60 and 80%"),
    ("4", "v80-100", "visibility of whole object is between 80 and 100%"),
)


def token(seed: int, *parts: Any) -> str:
    """A deterministic 32-hex nuScenes-style token."""
    return hashlib.md5("/".join(map(str, (GENERATOR, seed, *parts))).encode()).hexdigest()


def quaternion_from_yaw(yaw: float) -> list[float]:
    """(w, x, y, z) of a rotation by ``yaw`` about +z."""
    return [math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)]


def write_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename."""
    path = os.fspath(path)
    folder = os.path.dirname(path) or "."
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _json_bytes(obj: Any) -> bytes:
    return json.dumps(obj, indent=0, separators=(",", ":")).encode("utf-8")


def build_tables(
    scenarios: list[Scenario], *, seed: int, camera: Camera, sweeps: bool = True
) -> tuple[dict[str, list[dict]], list[tuple[str, float, Scenario]]]:
    """The 13 nuScenes tables for ``scenarios``, plus the images to draw as ``(filename, t, scenario)``."""
    t: dict[str, list[dict]] = {name: [] for name in TABLES}
    images: list[tuple[str, float, Scenario]] = []
    cat_tokens = {name: token(seed, "category", name) for name, _ in CATEGORIES}
    attr_tokens = {name: token(seed, "attribute", name) for name, _ in ATTRIBUTES}
    t["category"] = [{"token": cat_tokens[n], "name": n, "description": d} for n, d in CATEGORIES]
    t["attribute"] = [{"token": attr_tokens[n], "name": n, "description": d} for n, d in ATTRIBUTES]
    t["visibility"] = [{"token": tok, "level": lvl, "description": d} for tok, lvl, d in VISIBILITIES]
    sensor_token = token(seed, "sensor", CHANNEL)
    cs_token = token(seed, "calibrated_sensor", CHANNEL)
    t["sensor"] = [{"token": sensor_token, "channel": CHANNEL, "modality": "camera"}]
    t["calibrated_sensor"] = [
        {
            "token": cs_token,
            "sensor_token": sensor_token,
            "translation": list(camera.translation),
            "rotation": list(camera.rotation),
            "camera_intrinsic": camera.intrinsic.tolist(),
        }
    ]
    maps: dict[str, list[str]] = {}

    for scn in scenarios:
        i = scn.index
        log_name = f"synth-{seed:04d}-{i:04d}-{scn.location}"
        log_token = token(seed, "log", i)
        maps.setdefault(scn.location, []).append(log_token)
        t["log"].append(
            {
                "token": log_token,
                "logfile": log_name,
                "vehicle": "synth",
                "date_captured": "2018-08-01",
                "location": scn.location,
            }
        )
        scene_token = token(seed, "scene", i)
        kf_times = list(scn.keyframe_times_us)
        sample_tokens = [token(seed, "sample", i, k) for k in range(len(kf_times))]
        for k, ts in enumerate(kf_times):
            t["sample"].append(
                {
                    "token": sample_tokens[k],
                    "timestamp": ts,
                    "prev": sample_tokens[k - 1] if k > 0 else "",
                    "next": sample_tokens[k + 1] if k + 1 < len(kf_times) else "",
                    "scene_token": scene_token,
                }
            )
        t["scene"].append(
            {
                "token": scene_token,
                "log_token": log_token,
                "nbr_samples": len(kf_times),
                "first_sample_token": sample_tokens[0],
                "last_sample_token": sample_tokens[-1],
                "name": scn.name,
                "description": scn.description,
            }
        )
        # CAM_FRONT sample_data chain: keyframe, 5 sweeps, keyframe, ...
        records: list[tuple[int, bool, str]] = []  # (timestamp, is_key_frame, sample_token)
        sweep_lists = sweep_times_us(scn.keyframe_times_us) if sweeps else [[] for _ in kf_times[1:]]
        for k, ts in enumerate(kf_times):
            records.append((ts, True, sample_tokens[k]))
            if k + 1 < len(kf_times):
                records.extend((sw, False, sample_tokens[k + 1]) for sw in sweep_lists[k])
        sd_tokens = [token(seed, "sample_data", i, ts) for ts, _, _ in records]
        secs = scn.seconds([ts for ts, _, _ in records])
        poses = scn.pose(secs)
        for j, ((ts, key, st), pose) in enumerate(zip(records, poses)):
            ep_token = token(seed, "ego_pose", i, ts)
            t["ego_pose"].append(
                {
                    "token": ep_token,
                    "timestamp": ts,
                    "rotation": quaternion_from_yaw(float(pose[2])),
                    "translation": [float(pose[0]), float(pose[1]), 0.0],
                }
            )
            folder = "samples" if key else "sweeps"
            filename = f"{folder}/{CHANNEL}/{log_name}__{CHANNEL}__{ts}.jpg"
            t["sample_data"].append(
                {
                    "token": sd_tokens[j],
                    "sample_token": st,
                    "ego_pose_token": ep_token,
                    "calibrated_sensor_token": cs_token,
                    "timestamp": ts,
                    "fileformat": "jpg",
                    "is_key_frame": key,
                    "height": camera.height,
                    "width": camera.width,
                    "filename": filename,
                    "prev": sd_tokens[j - 1] if j > 0 else "",
                    "next": sd_tokens[j + 1] if j + 1 < len(records) else "",
                }
            )
            images.append((filename, float(secs[j]), scn))
        if scn.lead is not None:
            _lead_annotations(t, scn, seed, sample_tokens, cat_tokens["vehicle.car"], attr_tokens)
        for agent in synth_maps.scene_agents(scn):
            _agent_annotations(t, scn, agent, seed, sample_tokens, cat_tokens[agent.category], attr_tokens)

    for location, logs in sorted(maps.items()):
        map_token = token(seed, "map", location)
        t["map"].append(
            {
                "token": map_token,
                "log_tokens": logs,
                "category": "semantic_prior",
                "filename": f"maps/{map_token}.png",
            }
        )
    return t, images


def _lead_annotations(t, scn: Scenario, seed: int, sample_tokens: list[str], cat_token: str, attrs) -> None:
    """An instance and one sample_annotation per keyframe for the lead vehicle."""
    i = scn.index
    ann_tokens = [token(seed, "sample_annotation", i, k) for k in range(len(sample_tokens))]
    secs = scn.seconds(list(scn.keyframe_times_us))
    lead = scn.lead
    assert lead is not None
    attributes = [[attrs["vehicle.moving" if v > 0.1 else "vehicle.stopped"]] for v in lead.profile.v(secs)]
    _track(
        t,
        token(seed, "instance", i, "lead"),
        ann_tokens,
        sample_tokens,
        cat_token,
        scn.lead_pose(secs),
        lead,
        attributes,
        lidar_pts=120,
        radar_pts=3,
    )


def _agent_annotations(t, scn: Scenario, agent, seed: int, sample_tokens: list[str], cat_token: str, attrs) -> None:
    """An instance and one sample_annotation per keyframe for a parked or oncoming car or a pedestrian."""
    i = scn.index
    ann_tokens = [token(seed, "sample_annotation", i, agent.name, k) for k in range(len(sample_tokens))]
    secs = scn.seconds(list(scn.keyframe_times_us))
    poses = agent.pose(scn.path, float(scn.profile.s(0.0)), secs)
    if agent.category.startswith("vehicle."):
        attribute = [attrs["vehicle.moving" if abs(agent.v) > 0.1 else "vehicle.parked"]]
    else:
        attribute = []
    _track(
        t,
        token(seed, "instance", i, agent.name),
        ann_tokens,
        sample_tokens,
        cat_token,
        poses,
        agent,
        [attribute] * len(poses),
        lidar_pts=60,
        radar_pts=0,
    )


def _track(
    t,
    inst_token: str,
    ann_tokens: list[str],
    sample_tokens: list[str],
    cat_token: str,
    poses,
    box,
    attributes: list[list[str]],
    *,
    lidar_pts: int,
    radar_pts: int,
) -> None:
    """One instance and its chain of sample_annotations (one per keyframe pose (x, y, yaw); ``box`` has width,
    length and height in metres), as the nuScenes tables link them."""
    for k, pose in enumerate(poses):
        t["sample_annotation"].append(
            {
                "token": ann_tokens[k],
                "sample_token": sample_tokens[k],
                "instance_token": inst_token,
                "visibility_token": "4",
                "attribute_tokens": attributes[k],
                "translation": [float(pose[0]), float(pose[1]), box.height / 2],
                "size": [box.width, box.length, box.height],
                "rotation": quaternion_from_yaw(float(pose[2])),
                "prev": ann_tokens[k - 1] if k > 0 else "",
                "next": ann_tokens[k + 1] if k + 1 < len(ann_tokens) else "",
                "num_lidar_pts": lidar_pts,
                "num_radar_pts": radar_pts,
            }
        )
    t["instance"].append(
        {
            "token": inst_token,
            "category_token": cat_token,
            "nbr_annotations": len(ann_tokens),
            "first_annotation_token": ann_tokens[0],
            "last_annotation_token": ann_tokens[-1],
        }
    )


def _png(mask: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(mask, mode="L").save(buf, format="PNG")
    return buf.getvalue()


def _jpeg(img: Image.Image) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format="JPEG", quality=90)
    return buf.getvalue()


def _png_placeholder() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.zeros((64, 64), dtype=np.uint8), mode="L").save(buf, format="PNG")
    return buf.getvalue()


def _check_shared_files(root: Path, shared: list[tuple[str, Any]]) -> list[tuple[str, Any]]:
    """The entries of ``shared`` (``(path relative to root, () -> bytes)``) whose file does not exist yet.

    Raises:
        UserError: one of them exists with other bytes than this dataset's (the root holds another dataset,
            e.g. real nuScenes or a synthetic one of another seed, scene count, keyframes or image size);
            nothing has been written then.
    """
    missing = []
    for rel, produce in shared:
        path = root / rel
        if not path.exists():
            missing.append((rel, produce))
            continue
        if not path.is_file() or path.read_bytes() != produce():
            raise UserError(
                f"cannot write a synthetic dataset to {root}: {path} already exists with other contents, so the "
                "root holds another dataset (real nuScenes, or synthetic with a different seed, scenes, keyframes "
                "or image size); overwrite=True only replaces the version folder, never these shared files: "
                "write to a new folder",
                cli=f"cannot write a synthetic dataset to {root}: {path} already exists with other contents, so the "
                "root holds another dataset (real nuScenes, or synthetic with a different seed, --scenes, "
                "--keyframes or --image-size); --force only replaces the version folder, never these shared files: "
                "write to a new folder",
            )
    return missing


def write_dataset(
    outdir: str | os.PathLike[str],
    *,
    scenes: int = 8,
    seed: int = 0,
    version: str = "v1.0-mini",
    keyframes: int = 40,
    images: bool = True,
    sweeps: bool = True,
    image_size: tuple[int, int] = (800, 450),
    overwrite: bool = False,
    progress: bool = False,
) -> Path:
    """Write a synthetic nuScenes-format dataset to ``outdir`` and return its absolute path.

    Args:
        scenes: number of scenes; kinds cycle through :data:`lightemma.synth.KINDS`.
        seed: all parameters and tokens derive from it (same seed, same bytes).
        version: the version folder name (load it with ``split="all"`` or a scene list:
            the devkit's splits name real nuScenes scenes).
        keyframes: keyframes per scene (2 Hz).
        images: draw the JPEGs (``False`` writes tables only, e.g. for benchmarks).
        sweeps: also write the 12 Hz CAM_FRONT sweeps between keyframes.
        image_size: (width, height); the intrinsics are scaled to it.
        overwrite: rewrite the tables of an existing ``outdir/version`` instead of refusing
            (images of scenes no longer in the tables are left in place).

    Files outside the version folder (maps, map expansion, CAN bus, images) are shared by every version in
    ``outdir``: one that exists with the same bytes is kept, and one with other bytes makes this raise
    :class:`UserError` (the root holds another dataset) before anything is written, ``overwrite`` or not.
    """
    if not isinstance(version, str) or not version or os.sep in version or version in (".", ".."):
        raise UserError(f"invalid version folder name {version!r}")
    root = Path(outdir).expanduser().resolve()
    table_root = root / version
    blocker = next((p for p in (root, *root.parents) if p.exists()), None)
    if blocker is not None and not blocker.is_dir():
        raise UserError(f"cannot write a dataset to {root}: {blocker} is a file, not a folder")
    if table_root.exists() and not table_root.is_dir():
        raise UserError(f"cannot write version {version} to {root}: {table_root} is a file, not a folder")
    if table_root.exists() and any(table_root.iterdir()) and not overwrite:
        raise UserError(
            f"{table_root} already exists; pass overwrite=True to replace it",
            cli=f"{table_root} already exists; add --force to replace it",
        )
    camera = Camera(int(image_size[0]), int(image_size[1]))
    scenarios = synth_maps.build_scenarios(scenes, seed=seed, keyframes=keyframes)
    tables, todo = build_tables(scenarios, seed=seed, camera=camera, sweeps=sweeps)

    # Files outside the version folder are shared by every version written into this root: compute them all,
    # refuse before writing anything if one exists with other bytes, and write only the missing ones.
    masks: dict[str, bool] = {}
    shared: list[tuple[str, Any]] = []  # (path relative to root, () -> bytes)
    for location in sorted({s.location for s in scenarios}):
        here = [s for s in scenarios if s.location == location]
        doc = synth_maps.expansion_json(here, location, lambda *parts: token(seed, *parts))
        shared.append((f"maps/expansion/{location}.json", lambda doc=doc: _json_bytes(doc)))
        mask = synth_maps.mask_image(here)
        rec = next(r for r in tables["map"] if r["token"] == token(seed, "map", location))
        shared.append((rec["filename"], lambda mask=mask: _png(mask) if mask is not None else _png_placeholder()))
        masks[location] = mask is not None
    for scn in scenarios:
        shared.append((f"can_bus/{scn.name}_pose.json", lambda scn=scn: _json_bytes(synth_can.pose_messages(scn))))
    if images:
        for filename, secs, scn in todo:
            shared.append((filename, lambda secs=secs, scn=scn: _jpeg(render_frame(scn, secs, camera))))
    missing = _check_shared_files(root, shared)
    it: Any = missing
    if progress:
        from tqdm import tqdm

        it = tqdm(missing, desc="shared files", unit="file")
    for rel, produce in it:
        write_atomic(root / rel, produce())
    for name, rows in tables.items():
        write_atomic(table_root / f"{name}.json", _json_bytes(rows))
    info = {
        "generator": GENERATOR,
        "version": version,
        "seed": seed,
        "keyframes": keyframes,
        "images": images,
        "sweeps": sweeps,
        "image_size": list(image_size),
        # base map masks written per location (False: larger than synth.maps.MAX_MASK_PIXELS, a placeholder instead)
        "map_masks": masks,
        "scenes": [
            {
                "name": s.name,
                "kind": s.kind,
                "description": s.description,
                "params": s.params,
                "agents": [a.name for a in synth_maps.scene_agents(s)],
            }
            for s in scenarios
        ],
    }
    write_atomic(root / SYNTH_MARKER, json.dumps(info, indent=2).encode("utf-8"))
    return root
