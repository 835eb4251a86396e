"""Generated malformed inputs, second round (issue 42): Astyx folder layouts and model-file containers.

* ``Astyx layout``: a folder without one of its two sub-folders, a point cloud without labels (or labels
  without a point cloud), a stray file, an empty folder, a frame file that is a folder, a symbolic-link
  loop, a frame of no points, a header line in another order, the same frame named twice.
* ``model container``: a shipped model file whose ``.npz`` holds a pickled array, a structured or 0-d
  header, a header of another dtype, a header with a byte-order mark, duplicate JSON keys or ``NaN`` where
  a count stands, a stray array, or no header.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from sensor_envs.testing.fuzz_pieces import (
    SHIPPED,
    Case,
    Chooser,
    lidar_arrays,
    write_astyx,
    write_npz,
    write_radar_csv,
)

PC = "\nX Y Z V_r Mag\n10.0 1.0 0.0 0.0 50.0\n10.5 1.2 0.0 0.0 40.0\n"


def _astyx_layout(c: Chooser, d: Path) -> Case:
    from sensor_envs.radar.astyx import load_astyx

    root = write_astyx(d)
    pcs, gts = root / "radar_6455", root / "groundtruth_obj3d"
    kind = c.choice(["no pc dir", "no gt dir", "pc only", "gt only", "stray", "empty", "frame dir", "loop"])
    kind = c.choice([kind, "no points", "header order", "twice", "readme"])
    must = True
    if kind == "no pc dir":
        (pcs / "000000.txt").unlink()
        pcs.rmdir()
    elif kind == "no gt dir":
        (gts / "000000.json").unlink()
        gts.rmdir()
    elif kind == "pc only":
        (pcs / "000001.txt").write_text(PC)
        must = False  # a frame without labels: refused or skipped, judged by the loader
    elif kind == "gt only":
        (gts / "000001.json").write_text((gts / "000000.json").read_text())
        must = False
    elif kind == "stray":
        (pcs / "000000.txt.bak").write_text(PC)
        must = False  # not a .txt frame file: ignored, as the other files beside the frames
    elif kind == "empty":
        for p in (pcs / "000000.txt", gts / "000000.json"):
            p.unlink()
    elif kind == "frame dir":
        (pcs / "000001.txt").mkdir()
    elif kind == "loop":
        os.symlink(pcs / "000002.txt", pcs / "000001.txt")
        os.symlink(pcs / "000001.txt", pcs / "000002.txt")
    elif kind == "no points":
        (pcs / "000000.txt").write_text("\nX Y Z V_r Mag\n")
        must = False  # a frame with no detection is valid
    elif kind == "header order":
        (pcs / "000000.txt").write_text("\nMag V_r Z Y X\n50.0 0.0 0.0 1.0 10.0\n")
    elif kind == "twice":
        (pcs / "0.txt").write_text(PC)  # frame 0 again, under another name
    else:
        (root / "README.md").write_text("the Astyx HiRes2019 sample\n")
        must = False  # a file beside the two folders is no frame
    argv = ["record", "radar", "--astyx", str(root), "--out", str(d / "r.csv")]
    return Case("Astyx layout", kind, argv, lambda: load_astyx(root), must, [root])


def _header_of(data: dict[str, Any]) -> dict[str, Any]:
    return dict(json.loads(data["__header__"].tobytes().decode("utf-8")))


def _model_container(c: Chooser, d: Path) -> Case:
    from sensor_envs.lidar.lwlr import LidarLWLR
    from sensor_envs.modelio import read_model
    from sensor_envs.radar.gaussian import GaussianRadar
    from sensor_envs.radar.kde import KDERadarModel

    which = c.choice(["radar_kde.npz", "radar_gaussian.npz", "neato_lidar.npz"])
    cls = {"radar_kde.npz": KDERadarModel, "radar_gaussian.npz": GaussianRadar, "neato_lidar.npz": LidarLWLR}[which]
    with np.load(SHIPPED / which, allow_pickle=False) as z:
        data: dict[str, Any] = {k: z[k] for k in z.files}
    text = data["__header__"].tobytes().decode("utf-8")
    key = c.choice(sorted(k for k in data if k != "__header__"))
    kind = c.choice(["pickle", "header 0d", "header str", "header bom", "dup key", "stray", "no header", "struct"])
    must = True
    if kind == "pickle":
        obj = np.empty(np.shape(data[key]), dtype=object)
        obj[...] = 0.0
        data[key] = obj
    elif kind == "header 0d":
        data["__header__"] = np.array(text)
    elif kind == "header str":
        data["__header__"] = np.frombuffer(text.encode(), dtype=np.uint8).astype(np.int64)
        must = False  # the same bytes in wider integers: refused or read, never misread
    elif kind == "header bom":
        data["__header__"] = np.frombuffer(("\ufeff" + text).encode(), dtype=np.uint8)
        must = False
    elif kind == "dup key":
        dup = text.replace('"kind": ', '"kind": "x", "kind": ', 1)
        data["__header__"] = np.frombuffer(dup.encode(), dtype=np.uint8)
    elif kind == "stray":
        data["stray_array"] = np.zeros(3)
        must = False  # an unknown array: judged by the loader (the format names its arrays)
    elif kind == "no header":
        data.pop("__header__")
    else:
        data[key] = np.zeros(np.shape(data[key])[:1] or (1,), dtype=[("a", "<f8")])
    p = d / which
    np.savez(p, **data)
    log = write_radar_csv(d) if cls is not LidarLWLR else write_npz(d / "log.npz", lidar_arrays())
    argv = ["validate", "radar" if cls is not LidarLWLR else "lidar", str(p), str(log), "--out", str(d / "report")]
    what = f"{which}: {kind}" + (f" ({key})" if kind in ("pickle", "struct") else "")
    return Case("model container", what, argv, lambda: read_model(cls, p), must, [p, log], command_when_loaded=False)


FOLDER_FAMILIES = {"Astyx layout": _astyx_layout, "model container": _model_container}
"""Astyx layouts and model containers (:data:`sensor_envs.testing.fuzz_cases.FAMILIES` includes them)."""
