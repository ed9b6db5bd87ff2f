"""The package's shape: data flows one way and each part of the look is resolved in one place.

* ``forest.render.path`` (forest_path) is self-contained: it imports nothing from the rest of
  ``forest.render`` (the scalar renderer builds on it, never the reverse);
* the ``[lights]`` section is interpreted by :mod:`forest.lights` alone (every backend reads
  ``scene.lights`` or :func:`forest.lights.resolve_lights`);
* ``[render] terrain_texture`` is read by :mod:`forest.ground` alone (every backend reads the
  Scene's ``terrain_albedo``).

Checked on the source (imports by the syntax tree, attribute reads by name), so a new module that
breaks a rule fails here with its file and line.
"""

from __future__ import annotations

import ast
from pathlib import Path

import forest

ROOT = Path(forest.__file__).parent


def _modules():
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        yield path, name, ast.parse(path.read_text(), str(path))


def _imported(node: ast.AST, module: str, is_package: bool) -> list[str]:
    """Absolute names of the modules an import statement brings in."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if isinstance(node, ast.ImportFrom):
        if node.level == 0:
            base = node.module or ""
        else:
            parts = module.split(".")
            keep = len(parts) - node.level + (1 if is_package else 0)
            base = ".".join(parts[:keep] + ([node.module] if node.module else []))
        return [base] + [f"{base}.{a.name}" for a in node.names]
    return []


def test_forest_path_imports_nothing_from_the_rest_of_render():
    bad = []
    for path, name, tree in _modules():
        if not name.startswith("forest.render.path"):
            continue
        for node in ast.walk(tree):
            for target in _imported(node, name, path.name == "__init__.py"):
                if target.startswith("forest.render.") and not target.startswith("forest.render.path"):
                    bad.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}: imports {target}")
    assert not bad, "\n".join(bad)


def _reads(attr: str, owners: set[str] | None, allowed: set[str]) -> list[str]:
    """Reads of ``<owner>.<attr>`` (any owner when ``owners`` is None) outside the ``allowed`` modules and the
    config package, as ``file:line`` lines."""
    found = []
    for path, name, tree in _modules():
        if name in allowed or name.startswith("forest.config"):
            continue
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and node.attr == attr):
                continue
            v = node.value
            owner = v.id if isinstance(v, ast.Name) else v.attr if isinstance(v, ast.Attribute) else ""
            if owners is None or owner in owners:
                found.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}: reads {owner}.{attr}")
    return found


def test_the_lights_section_is_read_by_forest_lights_alone():
    """No module but forest.lights reads ``config.lights`` (look-dev's report edits the section it writes back)."""
    bad = _reads("lights", {"config", "cfg"}, {"forest.lights", "forest.lookdev.report"})
    assert not bad, "\n".join(bad)


def test_the_terrain_texture_is_read_by_forest_ground_alone():
    """No module but forest.ground reads ``[render] terrain_texture`` (the Scene compares it to know when to
    resolve the ground again)."""
    bad = _reads("terrain_texture", None, {"forest.ground", "forest.scene"})
    assert not bad, "\n".join(bad)


def test_the_preflight_lane_bound_is_forest_paths():
    """The pre-flight memory model bounds a JIT pass by forest_path's own pass size."""
    from forest.preflight import JIT_LANES
    from forest.render.path.frame import MAX_LANES

    assert JIT_LANES == MAX_LANES


def test_scenes_are_loaded_through_forest_runtime():
    """Every Mitsuba scene is built by :func:`forest.runtime.load_scene_dict`, which says whether Mitsuba
    builds its objects on threads (it does not pay: ``forest.runtime.PARALLEL_LOAD``): no other module
    calls ``load_dict`` on a ``{"type": "scene", ...}`` literal or passes ``parallel=``. The tree library's card
    renders (``forest.library.preview``) load one tree's few PLY parts and keep Mitsuba's default."""
    bad = []
    for path, name, tree in _modules():
        if name in ("forest.runtime", "forest.library.preview"):
            continue
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and getattr(node.func, "attr", None) == "load_dict"):
                continue
            arg = node.args[0] if node.args else None
            scene = isinstance(arg, ast.Dict) and any(
                isinstance(k, ast.Constant) and k.value == "type" and isinstance(v, ast.Constant) and v.value == "scene"
                for k, v in zip(arg.keys, arg.values)
            )
            if scene or any(k.arg == "parallel" for k in node.keywords):
                bad.append(f"{path}:{node.lineno}")
    assert not bad, "scenes loaded around forest.runtime.load_scene_dict:\n" + "\n".join(bad)
