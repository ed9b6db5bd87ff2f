"""Look-dev: fit a forest's look to a reference photo by rendering the production scene.

``forest match`` and the job service call :func:`match`; the steps live in
their own modules (see :mod:`forest.lookdev.match`): :mod:`.reference` and
:mod:`.regions` (what the photo is and where its sky, canopy and ground are),
:mod:`.renders` (the production scene at reduced resolution and samples),
:mod:`.params` and :mod:`.look` (what is fitted, its ranges and priors),
:mod:`.daylight` (light colours from colour temperatures), :mod:`.image_model`
(haze, exposure, white balance, clipping), :mod:`.correction` (the colour map
as the painted map times a smooth field), :mod:`.losses`, :mod:`.solve` (one
Gauss–Newton step, sparse per-channel Jacobian), :mod:`.fit` (the loop and its
guard rails) and :mod:`.report` (what is written).
"""

from __future__ import annotations

from .match import MatchResult, Settings, match, optimiser_size, parse_params, resolve_settings

__all__ = ["MatchResult", "Settings", "match", "optimiser_size", "parse_params", "resolve_settings"]
