"""Fill docs/estimators/realworld-ahrs.md from benchmarks/robust_ahrs_doc_template.md and the
computed JSON files.

    PYTHONPATH=src python benchmarks/robust_ahrs_doc.py

Reads docs/figures/robust_ahrs_{broad,ablation,tuning,speed}.json (written by the
commands listed in the page) so that every number on the page is computed.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"


def _row(cells):
    return "| " + " | ".join(cells) + " |"


def cross_tables(tun: dict, name: str) -> str:
    """The cross-data-set tuning table of filter ``name`` (``defaults_tuning.json``)."""
    f, vqf = tun["filters"][name], tun["vqf_deg"]
    pts = {json.dumps(p["params"], sort_keys=True): p for p in f["points"]}

    def cells(label, params):
        p = pts[json.dumps(params, sort_keys=True)]
        ps = ", ".join(f"{a}={b:g}" for a, b in params.items())
        return _row([label, ps] + [f"{p[d]:.3f} ({p[d + '_worst']:.1f})"
                                   for d in ("broad", "tyrex")])

    n = tun["trials"]
    lines = [_row(["chosen by", "parameters", f"BROAD, {n['broad']} trials",
                   f"tyrex, {n['tyrex']} trials"]), _row(["---"] * 4)]
    for d, v in f["directions"].items():
        lines.append(cells(f"tuned on {d.split('->')[0]}", v["params"]))
    lines.append(cells("joint", f["joint"]["params"]))
    lines.append(cells("default", f["default"]))
    lines.append(_row(["VQF (defaults)", "", f"{vqf['broad']:.3f}", f"{vqf['tyrex']:.3f}"]))
    return "\n".join(lines)


def main() -> str:
    broad = json.loads((FIG / "robust_ahrs_broad.json").read_text())
    abl = json.loads((FIG / "robust_ahrs_ablation.json").read_text())
    tun = json.loads((FIG / "robust_ahrs_tuning.json").read_text())
    speed = json.loads((FIG / "robust_ahrs_speed.json").read_text())
    methods = [m for m in ("robust-ahrs", "vqf", "eskf-r6", "mahony", "ahrs-madgwick", "imufusion")
               if m in broad["groups"]]
    lines = [_row(["group", "trials"] + [f"{m} total / heading / incl." for m in methods]),
             _row(["---"] * (2 + len(methods)))]
    for g, v in broad["groups"]["robust-ahrs"].items():
        cells = [g, str(v["trials"])]
        for m in methods:
            x = broad["groups"][m][g]
            cells.append(f"{x['total_deg']:.2f} / {x['heading_deg']:.2f} / "
                         f"{x['inclination_deg']:.2f}")
        lines.append(_row(cells))
    group_table = "\n".join(lines)
    mean = broad["mean"]
    means = "; ".join(f"{m} {mean[m]['total_deg']:.3f} / {mean[m]['heading_deg']:.3f} / "
                      f"{mean[m]['inclination_deg']:.3f}" for m in methods)
    by = {}
    for r in broad["trials"]:
        by.setdefault(r["trial"], {})[r["method"]] = r["total_deg"]
    worst = max(by, key=lambda k: by[k]["robust-ahrs"] / by[k]["vqf"])
    w = by[worst]
    worst_s = (f"{w['robust-ahrs'] / w['vqf']:.2f}x ({worst}: {w['robust-ahrs']:.2f} vs "
               f"{w['vqf']:.2f} deg)")
    abl_t = "\n".join([_row(["variant", "total", "heading", "inclination"]),
                       _row(["---"] * 4)]
                      + [_row([k, f"{v['total_deg']:.3f}", f"{v['heading_deg']:.3f}",
                               f"{v['inclination_deg']:.3f}"]) for k, v in abl.items()])
    tl = [_row(["fold", "chosen parameters", "tuning half: robust-ahrs / VQF",
                "held-out half: robust-ahrs / VQF", "all 15"]), _row(["---"] * 5)]
    for k, v in tun["folds"].items():
        ps = ", ".join(f"{a}={b}" for a, b in v["params"].items())
        tl.append(_row([k, ps, f"{v['tuning_mean_deg']:.3f} / {v['tuning_vqf_deg']:.3f}",
                        f"{v['held_out_mean_deg']:.3f} / {v['held_out_vqf_deg']:.3f}",
                        f"{v['all_mean_deg']:.3f}"]))
    lg = [_row(["held-out group", "trials", "chosen parameters", "robust-ahrs", "VQF"]),
          _row(["---"] * 5)]
    for g, v in tun.get("leave_one_group_out", {}).items():
        ps = ", ".join(f"{a}={b}" for a, b in v["params"].items())
        lg.append(_row([g, str(v["trials"]), ps, f"{v['held_out_mean_deg']:.3f}",
                        f"{v['held_out_vqf_deg']:.3f}"]))
    cross_table = cross_tables(json.loads((FIG / "defaults_tuning.json").read_text()),
                               "robust-ahrs")
    sp = (f"robust-ahrs {speed['robust_ahrs_samples_per_s'] / 1e6:.2f} million samples/s, "
          f"VQF {speed['vqf_updateBatch_samples_per_s'] / 1e6:.2f} million samples/s "
          f"(ratio {speed['ratio']:.2f}; {speed['samples']} samples; the machine is shared, "
          f"so absolute numbers vary)")
    sps = broad.get("samples_per_s", {})
    cli_speed = ", ".join(f"{m} {sps[m] / 1e6:.2f}" for m in ("robust-ahrs", "vqf") if m in sps)
    cli_speed += " million samples/s"
    text = (ROOT / "benchmarks" / "robust_ahrs_doc_template.md").read_text()
    for key, val in (("{GROUP_TABLE}", group_table), ("{MEANS}", means), ("{WORST}", worst_s),
                     ("{ABLATION_TABLE}", abl_t), ("{TUNING_TABLE}", "\n".join(tl)),
                     ("{LOGO_TABLE}", "\n".join(lg)), ("{CROSS_TABLE}", cross_table),
                     ("{SPEED}", sp),
                     ("{CLI_SPEED}", cli_speed), ("{LOO_TABLES}", loo_tables())):
        text = text.replace(key, val)
    (ROOT / "docs" / "estimators" / "realworld-ahrs.md").write_text(text)
    return text


def loo_tables() -> str:
    """The leave-one-data-set-out tables from ``docs/figures/defaults_loo.json``
    (``benchmarks/defaults_loo.py``)."""
    path = ROOT / "docs" / "figures" / "defaults_loo.json"
    if not path.is_file():
        return "(run `python benchmarks/defaults_loo.py` for the tables)"
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from defaults_loo import render

    return render(json.loads(path.read_text()))


if __name__ == "__main__":
    main()
