"""Reading the LightEMMA reference scripts' result folders (the input of ``lightemma import``).

The reference scripts write ``<results>/<model>/output/<scene>.json``, one file
per scene, each frame with its history, ground truth, the three prompts and
answers (long texts as lists of lines of at most 80 characters), tokens and
seconds per stage. This module finds those folders, reads the files and checks
every frame; it never writes anything (:mod:`lightemma.runs.importer` does).

A frame is accepted only with a sample token, 6 finite ground-truth points,
6 finite history (speed, curvature) pairs and a stage-3 answer string; optional
parts (``obs_positions``, ``gt_actions``, camera, tokens, seconds) must have their
shape when present. Anything else is a :class:`FrameProblem`: named, skipped,
never scored. The format is described in ``docs/import.md``.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path
from typing import Any

from lightemma._files import FileRefused, file_kind
from lightemma._files import read_regular_file as _read_regular_file
from lightemma._text import unicode_clean, without_lone_surrogates
from lightemma.errors import InputError, UserError
from lightemma.runs.records import MAX_SECONDS, in_bounds, loads_bounded, token_count

SOURCE_FORMAT = "lightemma-reference-results"
LINE_WIDTH = 80  # the reference splits long texts into lines of at most this many characters
WINDOW_OFFSET = 7  # frame_index i is the scene's keyframe i + 7 (reference window)
# (stage, prompt key, answer key); the stage-3 answer is ``pred_actions_str``, one string
STAGE_KEYS: tuple[tuple[str, str, str], ...] = (
    ("scene", "scene_prompt", "scene_description"),
    ("intent", "intent_prompt", "driving_intent"),
    ("actions", "waypoint_prompt", "pred_actions_str"),
)
# what the reference's model handler returns, as if it were the model's text, when a call fails
_CALL_FAILURE = re.compile(
    r"^(Error generating response: |Unsupported model: |\w+ model or processor not initialized\."
    r"|Required [\w ]*modules? not available|[\w ]+ module not available)"
)
_RUN_SUFFIX = re.compile(r"_\d{8}-\d{6}$")  # predict.py names folders <model>_<YYYYmmdd-HHMMSS>
MAX_SCENE_FILE_BYTES = 256 * 2**20  # a reference scene file is well under 1 MB; a larger one is skipped, never read


class ReferenceFileError(Exception):
    """A scene file that cannot be read at all (not JSON, not a scene object)."""


def read_regular_file(path: Path, limit: int = MAX_SCENE_FILE_BYTES) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes; :class:`ReferenceFileError` otherwise
    (:func:`lightemma._files.read_regular_file`: opened non-blocking, checked on the descriptor, never read past
    ``limit`` + 1 bytes)."""
    try:
        return _read_regular_file(path, limit)
    except FileRefused as exc:
        if exc.kind == "too-large":
            raise ReferenceFileError(f"{exc.size} bytes, above the limit of {limit} bytes for a scene file") from None
        if exc.kind == "grew":
            raise ReferenceFileError(
                f"grew above the limit of {limit} bytes for a scene file while being read"
            ) from None
        raise ReferenceFileError(exc.reason.removeprefix("is ")) from None  # unreadable (…), not a regular file (…)


@dataclass
class FrameProblem:
    """Why one frame of a scene file was skipped."""

    where: str  # "scene-0101.json frame 3"
    reason: str

    def __str__(self) -> str:
        return f"{self.where}: {self.reason}"


@dataclass
class ModelFolder:
    """One model's result folder: ``<path>/output/*.json``."""

    path: Path
    files: list[Path]
    skipped: list[tuple[Path, str]] = field(default_factory=list)  # entries that are not scene files to read, and why

    @property
    def folder_name(self) -> str:
        return unicode_clean(self.path.name)  # a name of bytes that are not UTF-8: U+FFFD for each such byte

    @property
    def model_name(self) -> str:
        """The script's model name: the folder name without predict.py's ``_<timestamp>`` suffix."""
        return _RUN_SUFFIX.sub("", self.folder_name)


@dataclass
class StageCall:
    """One stage as the reference recorded it."""

    stage: str
    prompt: str | None
    text: str | None
    input_tokens: int | None
    output_tokens: int | None
    seconds: float | None
    call_failed: bool = False  # the text is the reference's error message, not a model answer


@dataclass
class ReferenceFrame:
    """One checked frame of a scene file; pairs keep the file's numbers as they were (int or float)."""

    scene_name: str
    frame_index: int | None
    sample_token: str
    timestamp: int | None
    image_name: str | None
    image_path: str | None
    camera: dict[str, Any] | None
    position: list[Any] | None
    heading: float | None
    history_positions: list[list[Any]] | None
    history_actions: list[list[Any]]
    gt_positions: list[list[Any]]
    gt_actions: list[list[Any]] | None
    calls: list[StageCall]
    reference_trajectory: list[list[Any]] | None  # what the reference itself integrated, when present
    soft_problems: list[str] = field(default_factory=list)  # tokens/seconds unreadable: kept as unknown

    @property
    def frame_id(self) -> str:
        return f"{self.scene_name}/{self.sample_token}"

    @property
    def answer(self) -> str:
        text = self.calls[-1].text
        return text if text is not None else ""


# ---------------------------------------------------------------- folders


def _has_scene_files(folder: Path) -> bool:
    return (folder / "output").is_dir() and any((folder / "output").glob("*.json"))


def _model_folder(path: Path) -> ModelFolder:
    """The scene files of ``path/output``: regular files of at most :data:`MAX_SCENE_FILE_BYTES`, symlinks
    included only when they stay inside the model folder; every other ``*.json`` entry is listed in ``skipped``."""
    files: list[Path] = []
    skipped: list[tuple[Path, str]] = []
    root = path.resolve()
    for entry in sorted((path / "output").glob("*.json")):
        try:
            if entry.is_symlink():
                target = entry.resolve()
                if not target.is_relative_to(root):
                    skipped.append((entry, f"a symlink leading outside {path} (to {target})"))
                    continue
            info = entry.stat()
        except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
            skipped.append((entry, f"unreadable ({getattr(exc, 'strerror', None) or exc})"))
            continue
        if not stat.S_ISREG(info.st_mode):
            skipped.append((entry, f"not a regular file ({file_kind(info.st_mode)})"))
        elif info.st_size > MAX_SCENE_FILE_BYTES:
            skipped.append(
                (entry, f"{info.st_size} bytes, above the limit of {MAX_SCENE_FILE_BYTES} bytes for a scene file")
            )
        else:
            files.append(entry)
    return ModelFolder(path=path, files=files, skipped=skipped)


def find_model_folders(src: str | os.PathLike[str]) -> list[ModelFolder]:
    """The model folders ``src`` names: a model folder (``src/output/*.json``), its ``output`` folder,
    or a folder holding model folders. Raises :class:`UserError` when it holds none."""
    src = Path(src)
    if not src.is_dir():
        raise UserError(f"{src} is not a folder (expected a reference result folder: <model>/output/*.json)")
    if _has_scene_files(src):
        return [_model_folder(src)]
    if src.name == "output" and any(src.glob("*.json")):
        return [_model_folder(src.parent)]
    found = [_model_folder(child) for child in sorted(src.iterdir()) if child.is_dir() and _has_scene_files(child)]
    if not found:
        raise UserError(f"{src} holds no reference results: expected <model>/output/<scene>.json files at or below it")
    return found


# ---------------------------------------------------------------- texts


def join_lines(value: Any) -> str | None:
    """A long text back from the reference's list of lines (joined with one space); a string is kept."""
    if isinstance(value, str):
        return value
    if isinstance(value, list):
        try:
            return " ".join(value)  # TypeError when an entry is not a string
        except TypeError:
            return None
    return None


def split_lines(text: str, width: int = LINE_WIDTH) -> list[str]:
    """The reference's own splitting of a long text (``format_long_text``), restated.

    Each non-blank line of ``text`` becomes one entry (stripped) when it is at
    most ``width`` characters long; a longer one is split into words re-joined
    greedily into lines of at most ``width`` characters.
    """
    out: list[str] = []
    for paragraph in text.split("\n"):
        if not paragraph.strip():
            continue
        if len(paragraph) <= width:
            out.append(paragraph.strip())
            continue
        line: list[str] = []
        length = 0
        for word in paragraph.split():
            if line and length + 1 + len(word) > width:
                out.append(" ".join(line))
                line, length = [word], len(word)
            elif not line:
                line, length = [word], len(word)
            else:
                line.append(word)
                length += 1 + len(word)
        if line:
            out.append(" ".join(line))
    return out


def as_stored(text: str) -> str:
    """``text`` as a reference file stores it and :func:`join_lines` gives it back (whitespace folded)."""
    return " ".join(split_lines(text))


# ---------------------------------------------------------------- values


class _Bad(Exception):
    pass


def _is_number(value: Any) -> bool:
    return type(value) in (int, float) and math.isfinite(value)


_NUMBER_TYPES = (int, float)
_NUMBER_TYPE_SET = frozenset(_NUMBER_TYPES)
_LIST, _TWO = {list}, {2}


def _all_finite_numbers(values: list[Any]) -> bool:
    """Every value an int or a float (never a bool) and their sum finite — so each is (loops in C). A sum that
    overflows only sends finite numbers to the slow path, which reads them one by one."""
    return set(map(type, values)) <= _NUMBER_TYPE_SET and math.isfinite(sum(values))


def _pairs(value: Any, n: int, what: str) -> list[list[Any]]:
    """``n`` pairs of finite numbers, as given; :class:`_Bad` naming ``what`` otherwise."""
    if (
        type(value) is list
        and len(value) == n
        and set(map(type, value)) == _LIST
        and set(map(len, value)) == _TWO
        and _all_finite_numbers(list(chain.from_iterable(value)))
    ):
        return value
    if not isinstance(value, list):
        raise _Bad(f"{what} is {'missing' if value is None else type(value).__name__}, expected {n} pairs")
    if len(value) != n:
        raise _Bad(f"{what} has {len(value)} entries, expected {n}")
    out = []
    for k, pair in enumerate(value):
        if not isinstance(pair, list) or len(pair) != 2:
            raise _Bad(f"{what}[{k}] is not a pair of numbers: {_short(pair)}")
        if not (_is_number(pair[0]) and _is_number(pair[1])):
            raise _Bad(f"{what}[{k}] = {_short(pair)} is not two finite numbers")
        out.append([pair[0], pair[1]])
    return out


def _optional_pairs(container: Mapping[str, Any], key: str, n: int, what: str) -> list[list[Any]] | None:
    return None if container.get(key) is None else _pairs(container[key], n, what)


def _numbers(value: Any, n: int, what: str) -> list[Any]:
    if type(value) is list and len(value) == n and _all_finite_numbers(value):
        return list(value)
    if not (type(value) is list and len(value) == n and all(_is_number(v) for v in value)):
        raise _Bad(f"{what} is not {n} finite numbers: {_short(value)}")
    return list(value)


def _camera(value: Any) -> dict[str, Any] | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise _Bad(f"camera_params is {type(value).__name__}, expected an object")
    intrinsic = value.get("camera_intrinsic")
    if not isinstance(intrinsic, list) or len(intrinsic) != 3:
        raise _Bad(f"camera_params.camera_intrinsic is not a 3×3 matrix: {_short(intrinsic)}")
    return {
        "rotation": _numbers(value.get("rotation"), 4, "camera_params.rotation"),
        "translation": _numbers(value.get("translation"), 3, "camera_params.translation"),
        "camera_intrinsic": [_numbers(row, 3, "camera_params.camera_intrinsic") for row in intrinsic],
    }


def _short(value: Any, limit: int = 60) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _count(value: Any) -> int | None:
    """A token count: a whole number 0..MAX_TOKENS (10^9 per call; 1e308 is no count), else None (unknown)."""
    return token_count(value)


def _stage_calls(frame: Mapping[str, Any], soft: list[str]) -> list[StageCall]:
    inference = frame.get("inference")
    if not isinstance(inference, dict):
        raise _Bad("no inference object (the three prompts and answers)")
    answer = inference.get("pred_actions_str")
    if not isinstance(answer, str):
        raise _Bad(
            f"inference.pred_actions_str (the stage-3 answer) is {'missing' if answer is None else type(answer).__name__}, expected a string"
        )
    tokens = frame.get("token_usage")
    times = frame.get("time_usage")
    calls = []
    for stage, prompt_key, text_key in STAGE_KEYS:
        text = join_lines(inference.get(text_key)) if stage != "actions" else answer
        if text is None and inference.get(text_key) is not None:
            raise _Bad(f"inference.{text_key} is neither text nor a list of lines")
        usage = tokens.get(prompt_key) if isinstance(tokens, dict) else None
        inp = _count(usage.get("input")) if isinstance(usage, dict) else None
        out = _count(usage.get("output")) if isinstance(usage, dict) else None
        if tokens is not None and (inp is None or out is None):
            soft.append(
                f"token_usage.{prompt_key} unreadable"
                if not isinstance(usage, dict)
                else f"token_usage.{prompt_key} = {_short(usage)} unreadable (a count is a whole number 0..10^9)"
            )
        seconds = times.get(prompt_key) if isinstance(times, dict) else None
        if seconds is not None and not in_bounds(seconds, MAX_SECONDS):  # finite, 0..a day per call
            soft.append(f"time_usage.{prompt_key} = {_short(seconds)} unreadable")
            seconds = None
        elif times is not None and seconds is None:
            soft.append(f"time_usage.{prompt_key} missing")
        failed = text is not None and not out and bool(_CALL_FAILURE.match(text))
        calls.append(
            StageCall(
                stage,
                join_lines(inference.get(prompt_key)),
                text,
                inp,
                out,
                float(seconds) if seconds is not None else None,
                failed,
            )
        )
    return calls


def check_frame(scene_name: str, frame: Any) -> ReferenceFrame:
    """One frame of a scene file, checked; raises :class:`ValueError` with the reason when it is unusable."""
    try:
        if not isinstance(frame, dict):
            raise _Bad(f"is {type(frame).__name__}, expected an object")
        token = frame.get("sample_token")
        if not isinstance(token, str) or not token.strip():
            raise _Bad("no sample_token")
        ego = frame.get("ego_info")
        if not isinstance(ego, dict):
            raise _Bad("no ego_info object")
        gt = _pairs(ego.get("gt_positions"), 6, "ego_info.gt_positions")
        history = _pairs(ego.get("obs_actions"), 6, "ego_info.obs_actions")
        history_positions = _optional_pairs(ego, "obs_positions", 8, "ego_info.obs_positions")
        gt_actions = _optional_pairs(ego, "gt_actions", 6, "ego_info.gt_actions")
        position = None if ego.get("position") is None else _numbers(ego["position"], 2, "ego_info.position")
        heading = ego.get("heading")
        if heading is not None and not _is_number(heading):
            raise _Bad(f"ego_info.heading = {_short(heading)} is not a finite number")
        index = frame.get("frame_index")
        if index is not None and not (type(index) is int and index >= 0):
            raise _Bad(f"frame_index = {_short(index)} is not a non-negative integer")
        soft: list[str] = []
        calls = _stage_calls(frame, soft)
        image_path = frame.get("image_path") if isinstance(frame.get("image_path"), str) else None
        image_name = frame.get("image_name") if isinstance(frame.get("image_name"), str) else None
        if image_name is None and image_path:
            image_name = image_path.replace("\\", "/").rsplit("/", 1)[-1]
        predictions = frame.get("predictions")
        trajectory = predictions.get("trajectory") if isinstance(predictions, dict) else None
        timestamp = frame.get("timestamp")
        return ReferenceFrame(
            scene_name=scene_name,
            frame_index=index,
            sample_token=token,
            timestamp=timestamp if type(timestamp) is int else None,
            image_name=image_name,
            image_path=image_path,
            camera=_camera(frame.get("camera_params")),
            position=position,
            heading=heading,
            history_positions=history_positions,
            history_actions=history,
            gt_positions=gt,
            gt_actions=gt_actions,
            calls=calls,
            reference_trajectory=trajectory if isinstance(trajectory, list) else None,
            soft_problems=soft,
        )
    except _Bad as exc:
        raise InputError(str(exc)) from None


@dataclass
class SceneFile:
    """What one scene file held: its frames (checked) and the frames that were skipped."""

    path: Path
    scene_name: str
    metadata_model: str | None
    timestamp: str | None
    frames: list[ReferenceFrame]
    problems: list[FrameProblem]


def read_scene_file(path: Path, data: bytes) -> SceneFile:
    """Check the bytes of one scene file; :class:`ReferenceFileError` when the file as a whole is unusable."""
    try:
        text = data.decode("utf-8")  # the scripts write UTF-8; decoding first is faster than json's detection
        doc = loads_bounded(text)
        if "\\ud" in text or "\\uD" in text:  # an escaped surrogate, maybe half an emoji: U+FFFD where it is alone
            doc = without_lone_surrogates(doc)
    except UnicodeDecodeError as exc:
        raise ReferenceFileError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise ReferenceFileError(
            f"not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno}; truncated?)"
        ) from None
    except ValueError as exc:
        raise ReferenceFileError(f"not usable JSON ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise ReferenceFileError("not a reference scene file (no 'frames' list)")
    info_value = doc.get("scene_info")
    info: dict[str, Any] = info_value if isinstance(info_value, dict) else {}
    given_name = info.get("name")
    scene_name = given_name if isinstance(given_name, str) and given_name else unicode_clean(path.stem)
    metadata_value = doc.get("metadata")
    metadata: dict[str, Any] = metadata_value if isinstance(metadata_value, dict) else {}
    frames: list[ReferenceFrame] = []
    problems: list[FrameProblem] = []
    seen: set[str] = set()
    ordered = sorted(enumerate(doc["frames"]), key=lambda item: _index_key(item[1], item[0]))
    for position, raw in ordered:
        index = raw.get("frame_index") if isinstance(raw, dict) else None
        where = f"{path.name} frame {index if index is not None else f'#{position}'}"
        try:
            frame = check_frame(scene_name, raw)
        except ValueError as exc:
            problems.append(FrameProblem(where, str(exc)))
            continue
        if frame.sample_token in seen:
            problems.append(FrameProblem(where, f"sample_token {frame.sample_token} appears twice; kept the first"))
            continue
        seen.add(frame.sample_token)
        frames.append(frame)
    model = metadata.get("model")
    stamp = metadata.get("timestamp")
    return SceneFile(
        path,
        scene_name,
        model if isinstance(model, str) else None,
        stamp if isinstance(stamp, str) else None,
        frames,
        problems,
    )


def _index_key(frame: Any, position: int) -> tuple[float, int]:
    """The reference evaluation's order: by frame_index (frames without one last), then file order."""
    index = frame.get("frame_index") if isinstance(frame, dict) else None
    return (index if type(index) is int else math.inf, position)


def iter_scene_files(
    folder: ModelFolder, contents: Sequence[bytes] | None = None
) -> Iterator[tuple[Path, SceneFile | ReferenceFileError]]:
    """Read each scene file of ``folder`` in name order; a file that cannot be read yields its error."""
    for i, path in enumerate(folder.files):
        try:
            data = contents[i] if contents is not None else read_regular_file(path)
        except ReferenceFileError as exc:
            yield path, exc
            continue
        try:
            yield path, read_scene_file(path, data)
        except ReferenceFileError as exc:
            yield path, exc
