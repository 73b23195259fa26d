"""The figure of a benchmark: mean total RMSE per method and per group."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["group_kinds", "plot_benchmark"]

_KIND_ORDER = ("phone", "disturbance", "motion")


def group_kinds(res: dict) -> list[str]:
    """The kinds of groups in a result (``phone``, ``disturbance``, ``motion`` first), from
    group names ``kind:value``."""
    kinds = {g.partition(":")[0] for m in res.get("groups", {}) for g in res["groups"][m]
             if ":" in g}
    return [k for k in _KIND_ORDER if k in kinds] + sorted(kinds - set(_KIND_ORDER))


def plot_benchmark(res: dict, path, title: str = "") -> Path:
    """Mean total RMSE per method for every group of a ``run_tyrex``/``run_benchmark``
    result (one panel per kind of group: ``phone``, ``motion``, ``disturbance``; one
    panel of all trials when there are no groups), log scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = sorted(res["mean"], key=lambda m: res["mean"][m]["total_deg"])
    kinds: dict[str, list[str]] = {}
    for m in res.get("groups", {}):
        for g in res["groups"][m]:
            kind, _, value = g.partition(":")
            if value and value not in kinds.setdefault(kind, []):
                kinds[kind].append(value)
    panels = [("all trials", ["mean"])] + [(k, sorted(kinds[k])) for k in group_kinds(res)]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 3.2 * len(panels)), squeeze=False)
    w = 0.8 / max(len(methods), 1)
    for ax, (kind, values) in zip(axes[:, 0], panels, strict=True):
        x = np.arange(len(values))
        for j, m in enumerate(methods):
            if kind == "all trials":
                y = [res["mean"][m]["total_deg"]]
            else:
                y = [res["groups"].get(m, {}).get(f"{kind}:{v}", {}).get("total_deg", np.nan)
                     for v in values]
            ax.bar(x + j * w - 0.4 + w / 2, y, w, label=m)
        ax.set_xticks(x, values)
        ax.set_ylabel("mean total RMSE (deg)")
        ax.set_yscale("log")
        ax.set_title(kind)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", fontsize=8, ncol=min(len(methods), 6))
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
