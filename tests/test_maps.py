import json

import numpy as np
import pytest

from sensor_envs.maps import BUILTIN_MAPS, load_map, occupancy_to_segments, read_ros_map


@pytest.mark.parametrize("name", sorted(BUILTIN_MAPS))
def test_builtin_maps_load(name):
    m = load_map(name)
    assert m.segments.ndim == 3 and m.segments.shape[1:] == (2, 2) and len(m.segments) >= 4


def test_seed_room_matches_the_paper_geometry(real_data):
    real = np.load(real_data / "neato_mar27_train.npz")["map_segments"]
    assert load_map("seed_room").segments == pytest.approx(real)


def test_text_json_yaml_formats_agree(tmp_path):
    segs = [[0, 0, 2, 0], [2, 0, 2, 1], [2, 1, 0, 1], [0, 1, 0, 0]]
    (tmp_path / "m.txt").write_text("# a box\n" + "\n".join(" ".join(map(str, s)) for s in segs) + "\n")
    (tmp_path / "m.json").write_text(json.dumps({"name": "box", "segments": segs}))
    (tmp_path / "m.yaml").write_text("name: box\nsegments:\n" + "".join(f"  - {s}\n" for s in segs))
    ref = np.asarray(segs, dtype=float).reshape(-1, 2, 2)
    for f in ("m.txt", "m.json", "m.yaml"):
        assert load_map(tmp_path / f).segments == pytest.approx(ref)
    assert load_map(tmp_path / "m.json").name == "box"


@pytest.mark.parametrize(
    "content, suffix, msg",
    [
        ("", ".txt", "no segments"),
        ("0 0 1 nan\n", ".txt", "four numbers"),
        ("0 0 0 0\n", ".txt", "zero length"),
        ("0 0 1\n", ".txt", "expected four numbers"),
        ("0 0 a 1\n", ".txt", "expected four numbers"),
        ('{"segments": []}', ".json", "no segments"),
        ('{"segs": []}', ".json", "'segments'"),
        ("{not json", ".json", "not valid JSON"),
    ],
)
def test_bad_maps_raise_naming_file_and_problem(tmp_path, content, suffix, msg):
    f = tmp_path / f"bad{suffix}"
    f.write_text(content)
    with pytest.raises(ValueError, match=msg) as err:
        load_map(f)
    assert "bad" in str(err.value)


def test_unreadable_or_unknown_map(tmp_path):
    with pytest.raises(ValueError, match="neither a built-in map"):
        load_map(tmp_path / "missing.txt")
    f = tmp_path / "binary.txt"
    f.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(ValueError, match="cannot read map file"):
        load_map(f)


def test_occupancy_grid_boundaries_and_ros_map(tmp_path):
    grid = np.zeros((4, 5), dtype=bool)
    grid[1:3, 1:4] = True  # a 3 x 2 block of cells
    segs = occupancy_to_segments(grid, 0.5, (1.0, 2.0, 0.0))
    total = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1).sum()
    assert total == pytest.approx(2 * (1.5 + 1.0))  # perimeter of the block, merged into runs
    assert len(segs) == 4
    # Same block as a map_server map: PGM row 0 is the top of the map.
    img = np.full((4, 5), 254, dtype=np.uint8)
    img[::-1][grid] = 0
    (tmp_path / "m.pgm").write_bytes(b"P5\n# test\n5 4\n255\n" + img.tobytes())
    (tmp_path / "m.yaml").write_text(
        "image: m.pgm\nresolution: 0.5\norigin: [1.0, 2.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    m = read_ros_map(tmp_path / "m.yaml")
    assert m.bounds == pytest.approx((1.5, 2.5, 3.0, 3.5))
    assert load_map(tmp_path / "m.yaml").segments == pytest.approx(m.segments)


def test_ros_map_missing_field(tmp_path):
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.5\n")
    with pytest.raises(ValueError, match="'origin' is missing"):
        read_ros_map(tmp_path / "m.yaml")


def test_real_ros_map_loads(real_data):
    m = load_map(real_data / "neato_ros1_bags" / "mymap.yaml")
    assert len(m.segments) > 100
