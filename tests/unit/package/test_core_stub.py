"""The stub of the compiled core (python/lightemma/_core.pyi) names the modes the core accepts.

`python -m mypy.stubtest lightemma._core` (.ci/run) checks names, parameters and defaults, but not the values of a
`Literal`: these tests check that every `Literal` alias of the stub lists exactly the runtime list that declares it
(`METHODS: list[_Method]` → `_Method` == `_core.METHODS`, in order), and that no string-mode parameter is a plain
`str`.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import lightemma
from lightemma import _core

STUB = Path(lightemma.__file__).resolve().parent / "_core.pyi"


def _stub() -> ast.Module:
    return ast.parse(STUB.read_text(encoding="utf-8"), filename=str(STUB))


def _literal_aliases(tree: ast.Module) -> dict[str, list[object]]:
    """`_Name: TypeAlias = Literal[...]` → the literal values, in order."""
    aliases = {}
    for node in tree.body:
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(node.annotation, ast.Name)
            and node.annotation.id == "TypeAlias"
            and isinstance(node.value, ast.Subscript)
            and isinstance(node.value.value, ast.Name)
            and node.value.value.id == "Literal"
        ):
            items = node.value.slice.elts if isinstance(node.value.slice, ast.Tuple) else [node.value.slice]
            aliases[node.target.id] = [ast.literal_eval(item) for item in items]
    return aliases


def _lists_of_aliases(tree: ast.Module) -> dict[str, str]:
    """Module constants annotated `list[_Alias]` → the alias name."""
    lists = {}
    for node in tree.body:
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(node.annotation, ast.Subscript)
            and isinstance(node.annotation.value, ast.Name)
            and node.annotation.value.id == "list"
            and isinstance(node.annotation.slice, ast.Name)
            and node.annotation.slice.id.startswith("_")
        ):
            lists[node.target.id] = node.annotation.slice.id
    return lists


def test_the_stub_declares_the_mode_aliases() -> None:
    tree = _stub()
    aliases = _literal_aliases(tree)
    assert {"_Method", "_Convention", "_ParseMode", "_ParseFailure", "_ParseStatus"} <= set(aliases), aliases
    lists = _lists_of_aliases(tree)
    assert set(lists.values()) == set(aliases), "every Literal alias is the type of a runtime list, and only those"


@pytest.mark.parametrize("name", sorted(_lists_of_aliases(_stub())))
def test_each_literal_alias_is_the_runtime_list(name: str) -> None:
    tree = _stub()
    alias = _lists_of_aliases(tree)[name]
    assert _literal_aliases(tree)[alias] == list(getattr(_core, name)), (
        f"_core.pyi's {alias} differs from _core.{name} = {getattr(_core, name)!r}"
    )


def test_no_string_mode_parameter_is_a_plain_str() -> None:
    tree = _stub()
    aliases = _literal_aliases(tree)
    checked = []
    for node in tree.body:
        if not isinstance(node, ast.FunctionDef):
            continue
        args = node.args.posonlyargs + node.args.args
        defaults = [None] * (len(args) - len(node.args.defaults)) + list(node.args.defaults)
        pairs = list(zip(args, defaults, strict=True)) + list(
            zip(node.args.kwonlyargs, node.args.kw_defaults, strict=True)
        )
        for arg, default in pairs:
            if isinstance(default, ast.Constant) and isinstance(default.value, str):
                annotation = arg.annotation
                assert isinstance(annotation, ast.Name) and annotation.id in aliases, (
                    f"{node.name}({arg.arg}=...) takes a mode by name: annotate it with a Literal alias"
                )
                assert default.value in aliases[annotation.id], f"{node.name}'s default {default.value!r}"
                checked.append(f"{node.name}.{arg.arg}")
    assert sorted(checked) == [
        "evaluate.convention",
        "frame_metrics.convention",
        "integrate.method",
        "parse_actions.mode",
    ]


def test_the_literal_modes_are_the_ones_the_core_accepts() -> None:
    """Every alias value is accepted by its kernel, and a name outside the alias is refused."""
    import numpy as np

    aliases = _literal_aliases(_stub())
    actions = np.zeros((1, 6, 2))
    for method in aliases["_Method"]:
        _core.integrate(actions, method=method)
    for convention in aliases["_Convention"]:
        _core.evaluate(actions, actions, convention=convention)
    for mode in aliases["_ParseMode"]:
        _core.parse_actions(["[(1, 0)] * 6"], mode=mode)
    with pytest.raises(ValueError, match="rk4"):
        _core.integrate(actions, method="rk4")
    with pytest.raises(ValueError, match="nuplan"):
        _core.evaluate(actions, actions, convention="nuplan")
    with pytest.raises(ValueError, match="loose"):
        _core.parse_actions(["x"], mode="loose")
