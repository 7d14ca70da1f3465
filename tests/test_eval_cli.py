"""`slamfront eval traj`, `slamfront eval descriptors`, the image-folder source with poses,
and every bad input of the localization workflow through the CLI (exit 2, one line naming file and line)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from slamfront.formats.poses import Trajectory, read_tum, write_tum
from tests.test_cli import _one_line_error
from tests.test_rgbd_sources import _tum_fixture


@pytest.fixture
def fr1(shared_data: Path) -> tuple[Path, Path]:
    folder = shared_data / "trajectories/fr1_gt_vs_est"
    return folder / "groundtruth.txt", folder / "estimated.txt"


def test_help(cli) -> None:
    for command in (["eval"], ["eval", "traj"], ["eval", "descriptors"]):
        with pytest.raises(SystemExit) as exit_info:
            cli(*command, "--help")
        assert exit_info.value.code == 0


def test_eval_traj_prints_ate_and_rpe(cli, fr1: tuple[Path, Path], tmp_path: Path) -> None:
    code, out, err = cli("eval", "traj", *fr1, "--max-difference", "0.01", "--plot", tmp_path / "t.png")
    assert code == 0, err
    assert "ate_rmse_m = 0.0230707" in out  # evo_ape tum groundtruth.txt estimated.txt -a: rmse 0.023071
    assert "rpe_rmse_m = 0.0310817" in out  # evo_rpe ... -a: rmse 0.031082
    assert "associated:   610 pose pairs" in out and (tmp_path / "t.png").exists()
    code, out, _ = cli("eval", "traj", *fr1, "--json", "--align", "sim3", "--delta", "0.5", "--delta-unit", "seconds")
    metrics = json.loads(out)
    assert metrics["alignment"] == "sim3" and 0.9 < metrics["alignment_scale"] < 1.1
    assert metrics["rpe_delta_unit"] == "seconds" and metrics["n_rpe_pairs"] > 500


def test_eval_traj_kitti_compares_pose_by_pose(cli, fr1: tuple[Path, Path], tmp_path: Path) -> None:
    gt, est = read_tum(fr1[0]), read_tum(fr1[1])
    for name, trajectory in (("gt.txt", gt), ("est.txt", est)):
        rows = trajectory.poses[:100, :3, :4].reshape(-1, 12)
        np.savetxt(tmp_path / name, rows, fmt="%.17g")
    code, out, err = cli("eval", "traj", tmp_path / "gt.txt", tmp_path / "est.txt", "--format", "kitti", "--json")
    assert code == 0, err
    assert json.loads(out)["n_associated"] == 100
    np.savetxt(tmp_path / "short.txt", est.poses[:90, :3, :4].reshape(-1, 12))
    line = _one_line_error(*cli("eval", "traj", tmp_path / "gt.txt", tmp_path / "short.txt", "--format", "kitti")[::2])
    assert "short.txt: 90 poses but" in line and "gt.txt has 100" in line


def test_eval_traj_bad_files(cli, fr1: tuple[Path, Path], tmp_path: Path) -> None:
    broken = tmp_path / "broken.txt"
    lines = fr1[1].read_text().splitlines()
    lines[6] = lines[6].replace(" ", " x", 1)
    broken.write_text("\n".join(lines))
    line = _one_line_error(*cli("eval", "traj", fr1[0], broken)[::2])
    assert "broken.txt:7: not a number" in line
    late = tmp_path / "late.txt"
    est = read_tum(fr1[1])
    write_tum(late, Trajectory(est.timestamps + 1000.0, est.poses))
    line = _one_line_error(*cli("eval", "traj", fr1[0], late)[::2])
    assert "late.txt vs" in line and "groundtruth.txt" in line and "no timestamps could be associated" in line
    line = _one_line_error(*cli("eval", "traj", fr1[0], tmp_path / "none.txt")[::2])
    assert "none.txt: no such file" in line


def test_eval_descriptors_on_real_images(cli, tmp_path: Path, shared_data: Path) -> None:
    out = tmp_path / "report"
    code, stdout, err = cli("eval", "descriptors", "images/loop10", "--descriptors", "orb,brief", "--target", "0",
                            "--target", "4", "--max-features", "500", "-o", out, "-q", "--json")
    assert code == 0, err
    metrics = json.loads(stdout)
    assert metrics["targets"] == [0, 4] and set(metrics["summary"]) == {"orb", "brief+sift"}
    # 1.png (frame 0) is revisited by 10.png (frame 9); 5.png (frame 4) is next to 6.png (frame 5)
    assert metrics["global_test"]["orb"]["0"][0][0] == 9
    assert metrics["global_test"]["orb"]["4"][0][0] == 5
    assert len(metrics["local_test"]["orb"]["4"]) == 21
    report = (out / "report.md").read_text()
    for text in ("table 3", "table 4", "Q/C", "local_test.png", "distances.png"):
        assert text in report
    assert (out / "local_test.png").exists() and (out / "distances.png").exists()


def test_eval_descriptors_on_a_recipe_source(cli, tmp_path: Path, write_recipe) -> None:
    recipe = write_recipe({"name": "tiny", "description": "x", "source": {"plugin": "synthetic", "params": {
        "mode": "stream", "laps": 1, "frames_per_traversal": 12, "route_length_m": 60,
        "image_width": 160, "image_height": 120}}})
    code, stdout, err = cli("eval", "descriptors", recipe, "--descriptors", "orb", "--targets", "2",
                            "--neighbours", "3", "--top", "3", "-o", tmp_path / "r", "-q")
    assert code == 0, err
    assert "| orb |" in stdout


@pytest.mark.parametrize(("descriptors", "expected"), [
    ("surf", "SURF is patented"), ("orbb", "unknown descriptor 'orbb'"), ("brief+nope", "unknown detector 'nope'"),
])
def test_eval_descriptors_refuses_unknown_names(cli, descriptors: str, expected: str) -> None:
    line = _one_line_error(*cli("eval", "descriptors", "images/loop10", "--descriptors", descriptors)[::2])
    assert expected in line


def test_eval_descriptors_target_outside_the_sequence(cli, shared_data: Path) -> None:
    line = _one_line_error(*cli("eval", "descriptors", "images/loop10", "--descriptors", "orb", "--target", "10",
                                "-q")[::2])
    assert "images/loop10: target frame(s) [10] outside the sequence of 10 frames" in line


def test_image_folder_with_poses_and_intrinsics(shared_data: Path) -> None:
    from slamfront_plugins.sources.image_folder import ImageFolder

    config = ImageFolder.Config.model_validate({
        "folder": shared_data / "rgbd/room_sample/color", "poses": shared_data / "rgbd/room_sample/pose.txt",
        "camera": "slambook_room", "step": 2,
    })
    frames = list(ImageFolder(config).frames())
    assert [f.sequence_index for f in frames] == [0, 2, 4]
    from slamfront.formats.poses import read_pose_lines

    poses = read_pose_lines(shared_data / "rgbd/room_sample/pose.txt").poses
    np.testing.assert_array_equal(frames[1].pose, poses[2])
    assert frames[0].camera.fx == 518.0 and frames[0].depth is None


# --- bad input through `slamfront run` ---------------------------------------------------


def _localize(source: dict, **localizer: object) -> dict:
    return {
        "name": "bad", "source": source,
        "descriptor": {"plugin": "local_features", "params": {"descriptor": "orb"}},
        "localizer": {"plugin": "keyframe", "params": {"pnp_refinement": True, **localizer}},
    }


def test_missing_depth_for_a_frame(cli, write_recipe, tmp_path: Path, shared_data: Path) -> None:
    root = tmp_path / "seq"
    sample = shared_data / "rgbd/room_sample"
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    for path in sorted((sample / "color").iterdir()):
        (root / "color" / path.name).symlink_to(path)
    for path in sorted((sample / "depth").iterdir())[:4]:  # the 5th frame has no depth
        (root / "depth" / path.name).symlink_to(path)
    recipe = write_recipe(_localize({"plugin": "rgbd_folder", "params": {"root": str(root), "camera": "slambook_room"}}))
    line = _one_line_error(*cli("run", recipe, "-o", tmp_path / "out", "-q")[::2])
    assert "color/5.png: no depth image named 5" in line


def test_depth_needed_for_refinement_but_the_source_has_none(cli, write_recipe, tmp_path: Path,
                                                             shared_data: Path) -> None:
    source = {"plugin": "image_folder", "params": {"folder": "rgbd/room_sample/color", "camera": "slambook_room"}}
    out = tmp_path / "out"
    line = _one_line_error(*cli("run", write_recipe(_localize(source)), "-o", out, "-q")[::2])
    assert "frame 0 (1.png): pnp_refinement needs depth" in line
    assert (out / "run.mcap").exists()  # the log is finalised, not lost


def test_unreadable_ground_truth_line(cli, write_recipe, tmp_path: Path) -> None:
    root = _tum_fixture(tmp_path / "tum")
    with open(root / "groundtruth.txt", "a") as f:
        f.write("1305031103.0 0 0 0 0 0 0\n")
    recipe = write_recipe(_localize({"plugin": "tum_rgbd", "params": {"root": str(root)}}))
    line = _one_line_error(*cli("run", recipe, "-o", tmp_path / "out", "-q")[::2])
    assert "groundtruth.txt:6: expected 8 numbers" in line


def test_timestamps_that_cannot_be_associated(cli, write_recipe, tmp_path: Path) -> None:
    root = _tum_fixture(tmp_path / "tum")
    (root / "depth.txt").write_text("# depth maps\n100.0 depth/x.png\n")
    recipe = write_recipe(_localize({"plugin": "tum_rgbd", "params": {"root": str(root)}}))
    line = _one_line_error(*cli("run", recipe, "-o", tmp_path / "out", "-q")[::2])
    assert "rgb.txt: no colour timestamp is within 0.02 s of one in depth.txt" in line


def test_pose_file_that_does_not_fit_the_images(cli, write_recipe, tmp_path: Path, shared_data: Path) -> None:
    poses = tmp_path / "pose.txt"
    poses.write_text("\n".join((shared_data / "rgbd/room_sample/pose.txt").read_text().splitlines()[:3]) + "\n")
    source = {"plugin": "image_folder", "params": {"folder": "rgbd/room_sample/color", "poses": str(poses)}}
    line = _one_line_error(*cli("run", write_recipe(_localize(source, pnp_refinement=False)), "-o",
                                tmp_path / "out", "-q")[::2])
    assert "pose.txt: 3 poses for 5 images" in line


@pytest.mark.parametrize(("change", "expected"), [
    ({"descriptor": {"plugin": "downsampled", "params": {}}}, "needs local features"),
    ({"localizer": {"plugin": "keyframe", "params": {"preselection": "descriptor_vector"}}}, "needs a descriptor with"),
    ({"localizer": {"plugin": "keyframe", "params": {"stream": "online", "exclude_self": True}}}, "exclude_self"),
])
def test_incompatible_localizer_settings(cli, write_recipe, tmp_path: Path, change: dict, expected: str) -> None:
    raw = _localize({"plugin": "synthetic", "params": {"frames_per_traversal": 4}})
    raw.update(change)
    line = _one_line_error(*cli("run", write_recipe(raw), "-o", tmp_path / "out", "-q")[::2])
    assert expected in line


def test_eval_traj_associates_like_evo_by_default(cli, fr1: tuple[Path, Path]) -> None:
    """No --max-difference: evo's 0.01 s window, so `evo_ape tum GT EST -a` prints the same ATE."""
    code, out, err = cli("eval", "traj", *fr1, "--all-intervals")
    assert code == 0, err
    assert "associated:   610 pose pairs" in out and "ate_rmse_m = 0.0230707" in out
    assert "rpe_all_intervals_rmse_m = " in out


def test_global_test_hit_rate_is_neutral_about_ties_and_zero_matches() -> None:
    """Frames with 0 matches are misses, whatever their distance to the target; a tie that
    straddles the cut counts the share of near frames in it, not the closest ones."""
    from slamfront.descriptor_eval import near_share

    counts = np.zeros(30, dtype=np.int64)  # nothing matched the target (frame 10) at all
    assert near_share(counts, 10, 5, 10) == 0.0  # before: the 5 closest frames, "100 %"
    counts[[9, 11, 25]] = [50, 40, 30]  # two neighbours and one far frame matched
    assert near_share(counts, 10, 5, 10) == pytest.approx(2 / 5)
    counts[[12, 28]] = 7  # a tie for the 4th and 5th slots... with one more near frame at 7
    counts[29] = 7
    assert near_share(counts, 10, 5, 10) == pytest.approx((2 + 2 * (1 / 3)) / 5)
    assert near_share(np.array([0, 3]), 0, 5, 10) == 1.0  # one other frame: the slots shrink to 1


def test_eval_descriptors_draws_sixteen_targets_by_default(cli, tmp_path: Path, write_recipe) -> None:
    recipe = write_recipe({"name": "tiny", "description": "x", "source": {"plugin": "synthetic", "params": {
        "mode": "stream", "laps": 1, "frames_per_traversal": 20, "route_length_m": 60,
        "image_width": 96, "image_height": 72}}})
    code, stdout, err = cli("eval", "descriptors", recipe, "--descriptors", "orb", "--neighbours", "2", "--top", "2",
                            "-o", tmp_path / "r", "-q", "--json")
    assert code == 0, err
    assert len(json.loads(stdout)["targets"]) == 16  # Barbosa 2017's 16
