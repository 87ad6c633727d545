"""The package's layering (docs/layout.md): no module imports from a layer above its own (imports inside functions
included), and no learner imports another learner."""

from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]

# bottom to top; a module belongs to the first (longest) prefix that names it
LAYERS: tuple[tuple[str, ...], ...] = (
    ("envs_jax",),
    ("jaxmac.ops", "jaxmac.seeds", "jaxmac.scenarios", "jaxmac.schedules", "jaxmac.encodings", "jaxmac.losses",
     "jaxmac.buckets"),
    ("jaxmac.config",),
    ("jaxmac.buffer", "jaxmac.networks", "jaxmac.collect"),
    ("jaxmac.algos.base", "jaxmac.algos.acting", "jaxmac.algos.targets", "jaxmac.algos.families"),
    ("jaxmac.algos",),  # the learners
    ("jaxmac.algos.registry",),
    ("jaxmac.presets", "jaxmac.trainer"),
    ("jaxmac.plotting", "jaxmac.drawing"),
    ("jaxmac.runs", "jaxmac.runs.evaluation"),
    ("jaxmac.study", "jaxmac.api"),
    ("jaxmac.cli", "jaxmac.config_files", "jaxmac"),
)
LEARNERS = "jaxmac.algos"


def layer_of(module: str) -> tuple[int, str]:
    best = None
    for level, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + "."):
                if best is None or len(prefix) > len(best[1]):
                    best = (level, prefix)
    assert best is not None, f"{module} is in no layer: add it to LAYERS"
    return best


def modules() -> dict[str, pathlib.Path]:
    found = {}
    for package in ("jaxmac", "envs_jax"):
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def imported(path: pathlib.Path, known: dict) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {name for name in names if name in known}


def learner_of(module: str) -> str | None:
    """``jaxmac.algos.X`` (or inside package X) when X is a learner, i.e. in the learners' layer."""
    level, prefix = layer_of(module)
    if prefix != LEARNERS or module == LEARNERS:
        return None
    return module.split(".")[2]


def test_no_module_imports_from_a_layer_above():
    known = modules()
    upward = []
    for module, path in known.items():
        level = layer_of(module)[0]
        for target in imported(path, known):
            if target == "jaxmac" and module.startswith("jaxmac"):
                continue  # the package itself (its __init__ only re-exports lazily)
            if layer_of(target)[0] > level:
                upward.append(f"{module} (layer {level}) imports {target} (layer {layer_of(target)[0]})")
    assert not upward, "\n".join(upward)


def test_no_learner_imports_another():
    known = modules()
    crossing = []
    for module, path in known.items():
        own = learner_of(module)
        if own is None:
            continue
        for target in imported(path, known):
            other = learner_of(target)
            if other is not None and other != own:
                crossing.append(f"{module} imports {target}")
    assert not crossing, "\n".join(crossing)


def test_the_layer_check_can_fail():
    assert layer_of("jaxmac.config")[0] < layer_of("jaxmac.algos.tomacvf.model")[0]
    assert learner_of("jaxmac.algos.tomacvf.model") == "tomacvf" and learner_of("jaxmac.algos.base") is None
