"""baseline:ego — ridge from the history to the future actions: a closed-form check, the scene cross-fit that never
sees a frame's own scene, the fit on a training split, and runs that record the fit and resume under it."""

from __future__ import annotations

import asyncio
import json
from types import SimpleNamespace

import numpy as np
import pytest

import lightemma
from lightemma.backends.base import ChatRequest
from lightemma.backends.baseline import BaselineBackend
from lightemma.backends.ego import FEATURES, MIN_FIT_FRAMES, MIN_FIT_SCENES, TARGETS, EgoFit, ego_features
from lightemma.cli import main as cli_main
from lightemma.errors import UserError
from lightemma.pipeline import resume, run
from lightemma.runs.store import FRAMES_FILE, read_run


def make_frames(n_scenes: int = 6, per_scene: int = 5, seed: int = 0, odd: str | None = None) -> list[SimpleNamespace]:
    """Frames whose future follows one noisy law of the history; the ``odd`` scene's future is unlike any other."""
    rng = np.random.default_rng(seed)
    frames = []
    for s in range(n_scenes):
        scene = f"scene-{s:04d}"
        for i in range(per_scene):
            v0 = rng.uniform(2, 12)
            accel = rng.uniform(-1, 1)
            kappa = rng.uniform(-0.02, 0.02)
            v_hist = v0 + accel * 0.5 * np.arange(6)
            history = np.column_stack([v_hist, np.full(6, kappa) + rng.normal(0, 1e-3, 6)])
            v_fut = v_hist[-1] + accel * 0.5 * np.arange(1, 7) + rng.normal(0, 0.05, 6)
            future = np.column_stack([v_fut, np.full(6, kappa * 0.9)])
            if scene == odd:
                future = np.column_stack([np.full(6, 40.0) - v_fut, np.full(6, -0.3)])  # nothing else drives like this
            frames.append(
                SimpleNamespace(
                    frame_id=f"{scene}/t{i:03d}", scene_name=scene, history_actions=history, gt_actions=future
                )
            )
    return frames


def closed_form_ridge(X: np.ndarray, Y: np.ndarray, lam: float, X_new: np.ndarray) -> np.ndarray:
    """Ridge on standardised features with an unpenalised intercept: β = (ZᵀZ + λI)⁻¹ Zᵀ (Y − Ȳ)."""
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale[scale == 0] = 1.0
    Z = (X - mean) / scale
    beta = np.linalg.solve(Z.T @ Z + lam * np.eye(X.shape[1]), Z.T @ (Y - Y.mean(axis=0)))
    return ((X_new - mean) / scale) @ beta + Y.mean(axis=0)


def test_features_are_the_history_and_the_accelerations_and_yaw_rates_it_implies():
    history = np.array([[[4.0, 0.01], [5.0, 0.02], [5.5, 0.0], [5.5, -0.01], [6.0, 0.0], [7.0, 0.1]]])
    (f,) = ego_features(history)
    assert len(f) == len(FEATURES) == 23 and len(TARGETS) == 12
    np.testing.assert_allclose(f[:6], [4.0, 5.0, 5.5, 5.5, 6.0, 7.0])
    np.testing.assert_allclose(f[6:12], [0.01, 0.02, 0.0, -0.01, 0.0, 0.1])
    np.testing.assert_allclose(f[12:17], [2.0, 1.0, 0.0, 1.0, 2.0])  # (v_{k+1} − v_k) / 0.5 s
    np.testing.assert_allclose(f[17:], [0.04, 0.1, 0.0, -0.055, 0.0, 0.7])  # v·κ


def test_a_fit_on_a_training_split_equals_the_closed_form_ridge_solution():
    train, test = make_frames(4, 6, seed=1), make_frames(2, 3, seed=2)
    for f in test:
        f.scene_name = "eval-" + f.scene_name
        f.frame_id = "eval-" + f.frame_id
    lam = 3.0
    fit = EgoFit.fit_split(train, test, split="train", lambdas=(lam,))
    X = ego_features(np.stack([f.history_actions for f in train]))
    Y = np.stack([f.gt_actions for f in train]).reshape(len(train), 12)
    X_new = ego_features(np.stack([f.history_actions for f in test]))
    expected = closed_form_ridge(X, Y, lam, X_new)
    got = np.stack([fit.predictions[f.frame_id].reshape(12) for f in test])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
    # the recorded linear map (original units) gives the same predictions
    record = fit.record["fit"]
    W, b = np.array(record["coefficients"]), np.array(record["intercepts"])
    np.testing.assert_allclose(X_new @ W.T + b, expected, rtol=1e-9, atol=1e-9)
    assert record["lambda"] == lam and fit.record["features"] == list(FEATURES) and fit.record["fit_split"] == "train"


def test_a_written_two_feature_example_matches_the_textbook_formula():
    """A hand-checkable case: the fit depends on λ as (ZᵀZ + λI)⁻¹ZᵀY predicts, and λ → 0 is least squares."""
    train = make_frames(3, 4, seed=5)
    test = [SimpleNamespace(frame_id="x/1", scene_name="x", history_actions=train[0].history_actions, gt_actions=None)]
    X = ego_features(np.stack([f.history_actions for f in train]))
    Y = np.stack([f.gt_actions for f in train]).reshape(len(train), 12)
    small = EgoFit.fit_split(train, test, split="train", lambdas=(1e-3,)).predictions["x/1"].reshape(12)
    big = EgoFit.fit_split(train, test, split="train", lambdas=(1e6,)).predictions["x/1"].reshape(12)
    np.testing.assert_allclose(small, closed_form_ridge(X, Y, 1e-3, X[:1])[0], rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(big, Y.mean(axis=0), atol=1e-3 * np.abs(Y).max())  # all shrunk to the intercept


def test_the_cross_fit_never_uses_a_frames_own_scene():
    odd = "scene-0002"
    frames = make_frames(6, 5, odd=odd)
    fit = EgoFit.cross_fit(frames)
    own = [f for f in frames if f.scene_name == odd]
    others = [f for f in frames if f.scene_name != odd]
    # the odd scene is predicted from the others' law, far from its own future (which pulls the others' fits off less)
    err_odd = np.mean([np.abs(fit.predictions[f.frame_id][:, 0] - f.gt_actions[:, 0]).mean() for f in own])
    err_others = np.mean([np.abs(fit.predictions[f.frame_id][:, 0] - f.gt_actions[:, 0]).mean() for f in others])
    assert err_odd > 10 and err_odd > 2 * err_others
    # changing the odd scene's future changes none of its own predictions (no fit that predicts it saw it) …
    changed = make_frames(6, 5, odd=odd)
    for f in changed:
        if f.scene_name == odd:
            f.gt_actions = f.gt_actions * 0 + np.array([1.0, 0.2])
    refit = EgoFit.cross_fit(changed)
    for f in own:
        np.testing.assert_array_equal(refit.predictions[f.frame_id], fit.predictions[f.frame_id])
    # … while the frames it was fitted for do change
    assert any(not np.array_equal(refit.predictions[f.frame_id], fit.predictions[f.frame_id]) for f in others)


def test_the_cross_fit_records_folds_that_cover_each_scene_once_and_lambda_by_nested_cv():
    frames = make_frames(7, 3)
    fit = EgoFit.cross_fit(frames, folds=3)
    folds = fit.record["folds"]
    assert len(folds) == 3
    predicted = [s for fold in folds for s in fold["predicted_scenes"]]
    assert sorted(predicted) == sorted({f.scene_name for f in frames})
    for fold in folds:
        assert fold["lambda"] in fit.record["lambdas"] and fold["fit_scenes"] == 7 - len(fold["predicted_scenes"])
        assert fold["cv_folds"] == 3 and len(fold["cv_mse_standardised"]) == len(fit.record["lambdas"])
        assert np.array(fold["coefficients"]).shape == (12, 23)
    assert fit.record["frames_predicted"] == 21
    again = EgoFit.cross_fit(frames, folds=3)  # deterministic
    assert again.record == fit.record


def test_the_cross_fit_needs_three_scenes_and_a_split_fit_refuses_shared_scenes():
    with pytest.raises(UserError, match="at least 3 scenes"):
        EgoFit.cross_fit(make_frames(2, 4))
    frames = make_frames(4, 3)
    with pytest.raises(UserError, match="in the training split too"):
        EgoFit.fit_split(frames, frames[:3], split="train")


def test_the_backend_answers_from_its_fit_and_only_for_fitted_frames():
    frames = make_frames(4, 3)
    backend = BaselineBackend("ego")
    unfitted = asyncio.run(
        backend.generate([ChatRequest(text="", stage="actions", frame_id=frames[0].frame_id, frame=frames[0])])
    )
    assert unfitted[0].error == "ValueError" and "not fitted" in unfitted[0].error_message
    backend.prepare(frames)
    results = asyncio.run(
        backend.generate([ChatRequest(text="", stage="actions", frame_id=f.frame_id, frame=f) for f in frames])
    )
    parsed = lightemma.parse_actions([r.text for r in results], mode="strict")
    assert set(parsed.status) == {"ok"}
    reference = EgoFit.cross_fit(frames).predictions
    expected = np.stack([reference[f.frame_id] for f in frames])
    np.testing.assert_allclose(parsed.actions, expected, atol=1e-6)
    assert backend.info["fit"]["method"].startswith("cross-fit by scene")
    stranger = SimpleNamespace(**{**vars(frames[0]), "frame_id": "other/t0"})
    (missing,) = asyncio.run(
        backend.generate([ChatRequest(text="", stage="actions", frame_id="other/t0", frame=stranger)])
    )
    assert missing.error == "ValueError" and "no prediction" in missing.error_message
    with pytest.raises(UserError, match="--fit-split is for baseline:ego"):
        BaselineBackend("cv", fit_split="train")


@pytest.fixture(scope="module")
def four_scenes(tmp_path_factory):
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("synth4"), scenes=4, keyframes=16, image_size=(32, 18), sweeps=False)


def test_lightemma_run_baseline_ego_records_the_fit_and_resumes_under_it(four_scenes, tmp_path, capsys):
    code = cli_main(
        [
            "run",
            "--model",
            "baseline:ego",
            "--dataroot",
            str(four_scenes),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--output",
            str(tmp_path),
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    contents = read_run(run_dir)
    fit = contents.manifest["backend"]["fit"]
    assert fit["features"] == list(FEATURES) and len(fit["folds"]) == 4 and fit["frames_without_prediction"] == 0
    assert "subset" not in fit and "cross-fitted on the" not in err  # the whole set: no subset warning
    # but 4 scenes are few: each fold fits on 3 of them, and the run says so in one line (recorded as fit.warning)
    warned = [line for line in err.splitlines() if "baseline:ego is fitted on few frames" in line]
    assert warned == ["lightemma run: " + fit["warning"]]
    assert "as few as 3 scene(s)" in fit["warning"]
    assert all(r["status"] == "ok" for r in contents.records.values())
    frames = lightemma.load_frames(four_scenes, "v1.0-mini", split="all")
    expected = EgoFit.cross_fit(list(frames))
    for f in frames:
        np.testing.assert_allclose(contents.records[f.frame_id]["actions"], expected.predictions[f.frame_id], atol=1e-6)
    json.dumps(contents.manifest)
    # a resume refits, checks the predictions are the recorded ones, and finishes the lost frames identically
    path = run_dir / FRAMES_FILE
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:3]) + "\n")
    resume(run_dir, progress=False)
    again = read_run(run_dir).records
    assert {k: v["actions"] for k, v in again.items()} == {k: v["actions"] for k, v in contents.records.items()}
    manifest = json.loads((run_dir / "manifest.json").read_text())
    manifest["backend"]["fit"]["predictions_sha256"] = "sha256:other"
    (run_dir / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(UserError, match="fit gives other predictions"):
        resume(run_dir, progress=False)


@pytest.mark.parametrize("flag", [["--sample", "6"], ["--limit", "6"]])
def test_a_cross_fit_on_a_sample_or_limit_warns_in_one_line_and_is_recorded(four_scenes, tmp_path, capsys, flag):
    code = cli_main(
        [
            "run",
            "--model",
            "baseline:ego",
            "--dataroot",
            str(four_scenes),
            "--version",
            "v1.0-mini",
            "--split",
            "all",
            "--output",
            str(tmp_path),
            "--no-progress",
            *flag,
        ]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    (run_dir,) = [p.parent for p in tmp_path.glob("*/*/manifest.json")]
    fit = read_run(run_dir).manifest["backend"]["fit"]
    subset = fit["subset"]
    scenes = len({s for f in fit["folds"] for s in f["predicted_scenes"]})
    assert subset["taken_by"] == " ".join(flag) and subset["frames"] == 6 and subset["scenes"] == scenes >= 3
    assert (
        subset["fit_frames_per_fold"] == [f["fit_frames"] for f in fit["folds"]]
        and max(subset["fit_frames_per_fold"]) < 6
    )
    warned = [
        line
        for line in err.splitlines()
        if "baseline:ego is cross-fitted on the 6 frame(s) of " + " ".join(flag) in line
    ]
    assert len(warned) == 1 and f"({scenes} scenes;" in warned[0] and "--fit-split train" in warned[0]
    assert warned[0] == "lightemma run: " + subset["warning"]


def test_fit_split_is_for_baseline_ego_only_and_checks_its_split(four_scenes, tmp_path, capsys):
    code = cli_main(
        [
            "run",
            "--model",
            "baseline:cv",
            "--dataroot",
            str(four_scenes),
            "--version",
            "v1.0-mini",
            "--fit-split",
            "train",
            "--output",
            str(tmp_path),
            "--no-progress",
        ]
    )
    assert code == 2 and "--fit-split is for baseline:ego" in capsys.readouterr().err
    # the evaluated scenes are the training split's own: refused, not a leaked fit
    with pytest.raises(UserError, match="in the training split too"):
        run(
            "baseline:ego",
            dataroot=four_scenes,
            version="v1.0-mini",
            split="all",
            output=tmp_path,
            progress=False,
            backend_options={"fit_split": "all"},
        )


def test_a_fit_on_few_scenes_or_frames_carries_a_warning_and_a_large_one_none():
    """Before: the demo's ego baseline, cross-fitted on 8 synthetic scenes, predicted stopped cars accelerating (the
    worst baseline) with no word; a fit below MIN_FIT_SCENES scenes or MIN_FIT_FRAMES frames now says so."""
    small = EgoFit.cross_fit(make_frames(n_scenes=6, per_scene=5))
    per_fold = [(f["fit_scenes"], f["fit_frames"]) for f in small.record["folds"]]
    assert small.record["warning"].startswith(
        "warning: baseline:ego is fitted on few frames: each fold's fit sees as few as "
        f"{min(s for s, _ in per_fold)} scene(s) and {min(n for _, n in per_fold)} frame(s)"
    )
    assert "\n" not in small.record["warning"] and "--fit-split train" in small.record["warning"]
    # 30 scenes of 10 frames: each of the 5 folds fits on 24 scenes and 240 frames, above both limits
    large = EgoFit.cross_fit(make_frames(n_scenes=30, per_scene=10))
    assert min(f["fit_scenes"] for f in large.record["folds"]) >= MIN_FIT_SCENES
    assert min(f["fit_frames"] for f in large.record["folds"]) >= MIN_FIT_FRAMES and "warning" not in large.record
    # one fit on a training split: judged by its own scenes and frames
    frames = make_frames(n_scenes=8, per_scene=5)
    few = EgoFit.fit_split(frames[:30], frames[30:], split="train")
    assert "the fit on 'train' sees as few as 6 scene(s) and 30 frame(s)" in few.record["warning"]
