"""A fleet of robots, recalibrated over months: layout, engine (in-process or Ray), tracking, trends, report.

* :mod:`robocal.fleet.layout` — one folder per robot (serial, description, campaigns by date), checked;
* :mod:`robocal.fleet.engine` — per-robot tasks, cached by content hash, in-process or on Ray;
* :mod:`robocal.fleet.registry` — MLflow runs per campaign, model ``robot-<serial>``, alias ``production``;
* :mod:`robocal.fleet.trends` — which parameters moved more than their standard errors allow;
* :mod:`robocal.fleet.report` — the fleet's HTML page; :mod:`robocal.fleet.twin` — a twin fleet with events;
* :mod:`robocal.fleet.run` — all of it, as ``robocal fleet`` runs it; :mod:`robocal.fleet.dvc` — a DVC pipeline.

Importing this package loads nothing heavy (no Ray, no MLflow).
"""

from __future__ import annotations
