"""The exact command that re-runs one run of a campaign alone, from its ``campaign.json``.

Run ``index`` is fully described by the campaign's description (scenario, root seed,
``--vary``, task and its options) and the index (:mod:`gnomon.campaign.seeds`), so

    gnomon campaign SCENARIO --runs N --seed ROOT [--vary KEY=DIST ...] [--filter F ...]
                    --only INDEX

gives that run's row again (its metrics identical; ``elapsed_s``/``cpu_s`` aside).
:func:`rerun_command` writes that line, shell-quoted; for a campaign the command line
cannot express (a task other than the default, task options other than ``filters``, a
scenario given as a dict) it returns None and :func:`rerun_python` gives the Python call.
"""

from __future__ import annotations

import os
import shlex

from gnomon.campaign.default_task import DEFAULT_TASK

__all__ = ["rerun_command", "rerun_python", "scenario_argument"]


def scenario_argument(manifest: dict) -> str | None:
    """How the command line names the campaign's scenario: the preset's name, or the
    YAML file's path (relative to the working directory when it is below it); None for a
    scenario given as a dict."""
    source = str(manifest.get("scenario_source") or "")
    if source.startswith("preset:"):
        return source.split(":", 1)[1]
    if not source or source == "dict":
        return None
    if os.path.isabs(source):
        try:
            rel = os.path.relpath(source)
        except ValueError:   # another drive (Windows)
            return source
        return rel if not rel.startswith("..") else source
    return source


def rerun_command(manifest: dict, index: int) -> str | None:
    """The ``gnomon campaign ... --only INDEX`` line of run ``index`` of the campaign
    described by ``manifest`` (the dict in ``campaign.json``), or None (module docstring)."""
    scenario = scenario_argument(manifest)
    opts = dict(manifest.get("task_options") or {})
    filters = opts.pop("filters", None)
    if scenario is None or manifest.get("task", DEFAULT_TASK) != DEFAULT_TASK or opts:
        return None
    words = ["gnomon", "campaign", scenario, "--runs", str(int(manifest["runs"])),
             "--seed", str(int(manifest.get("root_seed", 0)))]
    for key, dist in (manifest.get("vary") or {}).items():
        words += ["--vary", f"{key}={dist}"]
    for f in filters or []:
        words += ["--filter", str(f)]
    words += ["--only", str(int(index))]
    return shlex.join(words)


def rerun_python(manifest: dict, index: int, campaign_dir: str = "CAMPAIGN_DIR") -> str:
    """The Python call that re-runs run ``index`` alone (any campaign), reading the
    description from ``campaign_dir/campaign.json``."""
    return ("import json, gnomon.campaign as c\n"
            f"m = json.load(open({str(campaign_dir) + '/campaign.json'!r}))\n"
            f"row = c.run_one(m['scenario'], {int(index)}, vary=m['vary'], "
            "root_seed=m['root_seed'], task=m['task'], task_options=m['task_options'])")
