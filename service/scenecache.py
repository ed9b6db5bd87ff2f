"""A worker's memory of loaded scenes, so frame after frame does not reload them.

Loading is what makes a one-frame task slow: parsing the config, scattering the
InstanceSet (seconds for tens of thousands of trees), opening the tree library, and
the renderer's set-up (terrain, materials, the Mitsuba scene).  A worker is a
long-lived process that takes task after task, and keeps

* the last loaded scene (or few: ``scenes``) by
  :attr:`~forest.service.models.TaskSpec.scene_key` (config text, overrides and input
  bytes), each with the dicts ``render_scene(reuse=…)`` and ``render_image(reuse=…)``
  keep their built renderers in — the oldest is let go *before* a new one loads, so a
  worker holds one scene's memory, not two;
* InstanceSets by their *scatter key* — the config without the sections that cannot
  change a scatter (camera, lights, render, level of detail, wind, look-dev, export)
  plus the input bytes — so a job that only moves the sun or the camera renders the
  same trees without scattering again.

:func:`load_scene` is the one place a task's scene is loaded.
"""

from __future__ import annotations

import gc
import time
import tomllib
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .models import TaskSpec, digest

#: Config sections a scatter never reads.
RENDER_ONLY = frozenset({"name", "camera", "lights", "render", "lod", "wind", "lookdev", "export"})


@dataclass
class LoadedScene:
    """What a worker keeps of one scene between tasks: the :class:`forest.scene.Scene` and built renderers."""

    key: str
    scene: Any  # forest.scene.Scene
    reuse: dict = field(default_factory=dict)  # render_scene(reuse=…): the built renderer
    quick: dict = field(default_factory=dict)  # render_image(reuse=…): the quick look's renderer
    load_seconds: float = 0.0
    scattered: bool = True  # False: the InstanceSet came from the cache

    @property
    def config(self) -> Any:
        """The scene's config."""
        return self.scene.config

    @property
    def instances(self) -> Any:
        """The scene's InstanceSet."""
        return self.scene.instances

    @property
    def library(self) -> Any:
        """The tree library the scene resolved its species from."""
        return self.scene.library


def scatter_key(spec: TaskSpec) -> str:
    """Same scatter-relevant config, overrides and inputs ⇒ the same InstanceSet."""
    data = tomllib.loads(spec.config)
    kept = {k: v for k, v in data.items() if k not in RENDER_ONLY}
    overrides = {k: v for k, v in spec.overrides.items() if k.split(".", 1)[0] not in RENDER_ONLY}
    return digest({"config": kept, "overrides": overrides, "inputs": spec.inputs})


def load_scene(spec: TaskSpec, input_dir: Path, instances: Any | None = None) -> LoadedScene:
    """The task's :class:`forest.scene.Scene`, with its inputs in ``input_dir``.

    ``instances``: an InstanceSet already scattered for this config (else it is scattered).
    """
    from forest.config import parse_config
    from forest.scene import load_scene as scene_of

    t0 = time.perf_counter()
    config = parse_config(spec.config, base_dir=input_dir, overrides=spec.overrides or None)
    if spec.kind in ("render", "flythrough", "match"):
        from forest.render.scene import check_render_inputs

        check_render_inputs(config)  # Mitsuba's test load of an environment map, named by its field
    scattered = instances is None
    return LoadedScene(
        key=spec.scene_key,
        scene=scene_of(config, instances),
        load_seconds=time.perf_counter() - t0,
        scattered=scattered,
    )


class SceneCache:
    """The last ``scenes`` loaded scenes and ``instance_sets`` InstanceSets of one worker (LRU)."""

    def __init__(self, *, scenes: int = 1, instance_sets: int = 2):
        self.scenes: OrderedDict[str, LoadedScene] = OrderedDict()
        self.instance_sets: OrderedDict[str, Any] = OrderedDict()
        self.max_scenes = max(0, scenes)
        self.max_instance_sets = max(0, instance_sets)
        self.hits = 0
        self.misses = 0

    def get(self, spec: TaskSpec, input_dir: Path) -> tuple[LoadedScene, bool]:
        """The task's scene and whether it came from the cache."""
        key = spec.scene_key
        hit = self.scenes.get(key)
        if hit is not None:
            self.scenes.move_to_end(key)
            self.hits += 1
            return hit, True
        self.misses += 1
        while self.scenes and len(self.scenes) >= self.max_scenes:
            self.scenes.popitem(last=False)  # let the oldest go before the new one is loaded
        gc.collect()
        skey = scatter_key(spec)
        inst = self.instance_sets.get(skey)
        scene = load_scene(spec, input_dir, inst)
        self._put(self.instance_sets, skey, scene.instances, self.max_instance_sets)
        self._put(self.scenes, key, scene, self.max_scenes)
        return scene, False

    @staticmethod
    def _put(cache: OrderedDict, key: str, value: Any, limit: int) -> None:
        if limit <= 0:
            return
        cache[key] = value
        cache.move_to_end(key)
        while len(cache) > limit:
            cache.popitem(last=False)

    def clear(self) -> None:
        """Forget every cached scene and InstanceSet."""
        self.scenes.clear()
        self.instance_sets.clear()

    def keys(self) -> list[str]:
        """Keys of the cached scenes, least recently used first."""
        return list(self.scenes)
