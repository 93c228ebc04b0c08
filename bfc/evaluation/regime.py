"""The paper's regime report (docs/report/paper_regime/): does the paper's Table 2 hold when the
paper is trained as written (+preset=paper) for as long as it asks?

It reads the sweep of `bench/paper_regime.sh` (runs paused on the way are read as far as they
went, and say so), flies every run's final policy on the test starts (bfc.evaluation.report's
Table 2), puts the result beside the paper's Table 2 and bfc's own (docs/report/table2), and
answers each of the paper's claims in each regime from the numbers, by the rules written under
the claims table. `bench/paper_regime_report.py` writes it.
"""

from __future__ import annotations

import json
from pathlib import Path

from bfc.config import TestProtocolConfig
from bfc.evaluation.report import (
    KEPT_SCALARS,
    fly_final_policies,
    mean_spread,
    read_runs,
    run_algo_and_variant,
    runs_sections,
    tb_scalars,
)

# The paper's Table 2 (success out of 100, mean over its seeds) and figs. 5-10 for the rest.
PAPER_TABLE2 = {"jd_css_tdts": 90.5, "jd_css": 67.0, "jd_tdts": 25.0, "jd": 16.0}
PAPER_NO_POLICY = ("ppo", "css", "tdts", "css_tdts")  # "did not learn a flight policy" (figs. 8-10)
TABLE2_ORDER = (*PAPER_TABLE2, *PAPER_NO_POLICY)
LEARNED = 0.5  # a variant "learns" when its mean final test success is at least this
NOTHING = 0.1  # and "does not learn" when it is below this
PLAIN = ("ppo", "trpo ppo", "ddpg ppo")  # the plain algorithms' row labels (figs. 5-7)


def protocol_means(by_variant: dict) -> dict[str, float]:
    """{row label: mean over seeds of the final policies' success on the protocol's test starts}."""
    out = {}
    for label, runs in by_variant.items():
        rates = [r.get("test", {}).get("protocol") for r in runs]
        known = [x for x in rates if x is not None]
        if known:
            out[label] = sum(known) / len(known)
    return out


def _runs_from_json(path: Path) -> dict[str, list[dict]]:
    return json.loads(path.read_text()) if path.is_file() else {}


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f}"


def _kind(rate: float) -> str:
    """learns (>= LEARNED), fails (< NOTHING) or partly (between)."""
    return "learns" if rate >= LEARNED else ("fails" if rate < NOTHING else "partly")


def what_decides(labels, means: dict[str, float], runs: dict[str, list[dict]]) -> str:
    """Why a verdict on the variants `labels` is undecided, and the frames that would decide it:
    the frames left in paused runs; else more seeds of a variant that learns partly (its seeds
    split); else, every run at the end of its schedule without learning, a longer one."""
    mine = [r for label in labels for r in runs.get(label, [])]
    left = sum(max(0, int(r["schedule_frames"]) - int(r.get("frames", 0))) for r in mine if r.get("paused"))
    if left:
        return f"{left / 1e6:.1f}M frames left in paused runs decide it"
    schedule = max((int(r["schedule_frames"]) for r in mine), default=0) / 1e6
    split = next((v for v in labels if v in means and _kind(means[v]) == "partly"), None)
    if split is not None:
        each = ", ".join(f"{100 * (r.get('test', {}).get('protocol') or 0.0):.0f}" for r in runs.get(split, []))
        return f"{split} learns partly (seeds {each}): more seeds of it, {schedule:g}M frames each, decide it"
    return f"every run ended its {schedule:g}M-frame schedule unlearned: only a longer schedule could decide it"


def claims(
    regime: dict[str, float], bfc: dict[str, float], algos: dict[str, float], runs: dict | None = None
) -> list[list[str]]:
    """[claim, the paper, the paper's regime, bfc's regime, what bfc changed] rows, each verdict
    computed from the means (protocol test success of the final policies) by the rules of
    CLAIM_RULES. With the paper's regime's `runs` ({label: [run]}), an undecided verdict there
    says why and what would decide it (what_decides)."""

    def why(labels, means: dict[str, float], runs: dict | None) -> str:
        return f"; {what_decides(labels, means, runs)}" if runs is not None else ""

    def necessary(means: dict[str, float], runs: dict | None = None) -> str:
        jd = {v: means[v] for v in ("jd", "jd_css", "jd_tdts", "jd_css_tdts") if v in means}
        no = {v: means[v] for v in PAPER_NO_POLICY if v in means}
        if not jd or not no:
            return "not measured"
        best_no, best_jd = max(no, key=no.get), max(jd, key=jd.get)
        figures = f"best without JD {best_no} {_pct(no[best_no])}, best with JD {best_jd} {_pct(jd[best_jd])}"
        if _kind(no[best_no]) == "learns":
            return f"does not hold ({figures})"
        if _kind(no[best_no]) == "fails" and _kind(jd[best_jd]) != "fails":
            return f"holds ({figures})"
        return f"undecided ({figures}){why([*no, *jd], means, runs)}"

    def ordered(means: dict[str, float], runs: dict | None = None) -> str:
        order = [v for v in ("jd_css_tdts", "jd_css", "jd_tdts", "jd") if v in means]
        if len(order) < 4:
            return "not measured"
        figures = ", ".join(f"{v} {_pct(means[v])}" for v in order)
        if all(_kind(means[v]) == "fails" for v in order):
            return f"undecided: none learned ({figures}){why(order, means, runs)}"
        holds = all(means[a] > means[b] for a, b in zip(order, order[1:], strict=False))
        return f"{'holds' if holds else 'does not hold'} ({figures})"

    def ppo_beats_trpo(means: dict[str, float], runs: dict | None = None) -> str:
        ppo, trpo = means.get("jd_css_tdts"), means.get("trpo jd_css_tdts")
        if ppo is None or trpo is None:
            return "not measured"
        figures = f"PPO {_pct(ppo)}, TRPO {_pct(trpo)}"
        if _kind(ppo) == _kind(trpo) == "fails":
            return f"undecided: neither learned ({figures}){why(['jd_css_tdts', 'trpo jd_css_tdts'], means, runs)}"
        return f"{'holds' if ppo > trpo else 'does not hold'} ({figures})"

    def plain_fail(means: dict[str, float], runs: dict | None = None) -> str:
        plain = {k: means[k] for k in PLAIN if k in means}
        if not plain:
            return "not measured"
        figures = ", ".join(f"{k.split()[0]} {_pct(v)}" for k, v in plain.items())
        kinds = [_kind(v) for v in plain.values()]
        if all(k == "fails" for k in kinds):
            verdict = "holds"
        elif any(k == "learns" for k in kinds):
            verdict = "does not hold" if all(k == "learns" for k in kinds) else "holds in part"
        else:
            verdict = "undecided"
        unrun = [k.split()[0] for k in PLAIN if k not in plain]
        missing = f"; {', '.join(unrun)} not run" if unrun else ""
        return f"{verdict} ({figures}){why(plain, means, runs) if verdict == 'undecided' else ''}{missing}"

    bfc_all = {**bfc, **algos}
    changed = (
        "bfc's reward (positive everywhere, docs/env.md), its observation (heading frame, rotation matrix, "
        'the last command), its thrust map and PPO settings (docs/training.md, "What made it learn")'
    )
    return [
        [
            "JD is necessary: without it no variant learns",
            "PPO, CSS, TDTS, CSS-TDTS learned no flight policy",
            necessary(regime, runs),
            necessary(bfc_all),
            changed,
        ],
        ["BFC > JD-CSS > JD-TDTS > JD", "90.5 > 67 > 25 > 16", ordered(regime, runs), ordered(bfc_all), changed],
        [
            "enhanced PPO beats enhanced TRPO",
            "PPO learned faster and better (figs. 5-7)",
            ppo_beats_trpo(regime, runs),
            ppo_beats_trpo(bfc_all),
            "TRPO with bfc's env and settings (docs/report/algos)",
        ],
        [
            "plain DDPG, TRPO and PPO do not learn",
            "none learned (figs. 5-7)",
            plain_fail(regime, runs),
            plain_fail(bfc_all),
            changed,
        ],
    ]


CLAIM_RULES = (
    f"Rules: a variant learns when the mean test success of its final policies is at least {100 * LEARNED:g}%, "
    f"fails below {100 * NOTHING:g}%, and learns partly in between. JD is necessary when every variant without "
    "it fails and one with it does not; it is not when one without it learns; otherwise undecided. An order "
    "holds when each mean is above the next (undecided when all four fail); PPO beats TRPO when its mean is "
    "higher (undecided when both fail); plain algorithms do not learn when all fail, do when all learn, in "
    "part when some learn. Runs paused on the way are judged as far as they went. An undecided verdict in "
    "the paper's regime says what would decide it: the frames left in paused runs, more seeds of a variant "
    "whose seeds split, or a schedule longer than the runs'. The paper's regime: the "
    "runs of this report; bfc's regime: docs/report/table2 and docs/report/algos (2M frames, three seeds)."
)


KEPT_FILES = ("summary.json", "config.yaml", "policy_last.pt")  # plus KEPT_SCALARS, from the events
KEPT_TAGS = ("train/episode_return",)


def keep_finished_runs(sweep_dirs, runs_dir) -> list[Path]:
    """Copy what the report reads of every finished run under `sweep_dirs` (its summary with the
    validation curve, its config, its final policy, its episode returns) to
    `runs_dir`/<variant>_seed<k>[_<algo>]/, so that the report rebuilds on a clone without the
    runs' folders. A paused run is left where it is (its checkpoint goes on there). Returns the
    directories written."""
    import shutil

    import yaml

    kept = []
    for summary in sorted(p for d in sweep_dirs for p in Path(d).rglob("summary.json")):
        run = summary.parent
        if json.loads(summary.read_text()).get("paused") or not all((run / f).is_file() for f in KEPT_FILES):
            continue
        cfg = yaml.safe_load((run / "config.yaml").read_text())
        algo, variant = run_algo_and_variant(cfg)
        name = f"{variant}_seed{cfg['seed']}" + ("" if algo == "ppo" else f"_{algo}")
        dest = Path(runs_dir) / name
        dest.mkdir(parents=True, exist_ok=True)
        for f in KEPT_FILES:
            shutil.copyfile(run / f, dest / f)
        scalars = {tag: _pairs(*tb_scalars(run, tag)) for tag in KEPT_TAGS}
        (dest / KEPT_SCALARS).write_text(json.dumps(scalars))
        kept.append(dest)
    return kept


def _pairs(frames, values) -> list[list[float]]:
    return [[int(f), round(float(v), 6)] for f, v in zip(frames.tolist(), values.tolist(), strict=True)]


def write_regime_report(
    sweep_dirs,
    out,
    bfc_table2=None,
    bfc_algos=None,
    protocol: TestProtocolConfig | None = None,
    header: str = "",
) -> Path:
    """report.md, learning_curves.png and table2.json in `out` for the runs under `sweep_dirs`,
    beside the paper's Table 2 and bfc's (the table2.json files of docs/report/table2 and algos)."""
    protocol = protocol or TestProtocolConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dirs = [Path(d) for d in sweep_dirs]
    by_variant = read_runs(*dirs)
    fly_final_policies(by_variant, protocol)
    regime = protocol_means(by_variant)
    bfc = protocol_means(_runs_from_json(Path(bfc_table2))) if bfc_table2 else {}
    algos = protocol_means(_runs_from_json(Path(bfc_algos))) if bfc_algos else {}

    runs = [r for rs in by_variant.values() for r in rs]
    frames = sum(int(r.get("frames", 0)) for r in runs)
    hours = sum(float(r.get("wall_seconds", 0.0)) for r in runs) / 3600
    paused = [r for r in runs if r.get("paused")]
    lines = ["# The paper's regime: does its Table 2 hold?", "", header, ""]
    lines += [
        "## Where the sweep stands",
        f"{len(runs)} runs, {frames / 1e6:.1f}M frames and {hours:.2f} h of training wall-clock in all"
        + (f"; {len(paused)} of them paused on the way (frames below their schedule's end)." if paused else "."),
        "",
        "| variant | seed | frames trained | of its schedule | state | training wall-clock (min) |",
        "|---|---|---|---|---|---|",
    ]
    for label, rs in by_variant.items():
        for r in rs:
            state = "paused" if r.get("paused") else "finished"
            schedule = r.get("schedule_frames")
            lines.append(
                f"| {label} | {r['seed']} | {int(r.get('frames', 0)):,} | "
                f"{'n/a' if schedule is None else f'{int(schedule):,}'} | {state} | "
                f"{float(r.get('wall_seconds', 0.0)) / 60:.1f} |"
            )
    summarised = {Path(r["dir"]).resolve() for r in runs}
    configs = [c for d in dirs for c in d.rglob("config.yaml") if c.parent.name != ".hydra"]  # bfc's, not Hydra's
    started = sorted(c.parent for c in configs if c.parent.resolve() not in summarised)
    for run_dir in started:  # a run that has written no summary yet: left out of every table below
        lines.append(f"| {run_dir.relative_to(run_dir.parents[1])} | | | | started, no summary yet | |")
    lines += [
        "",
        "## Table 2 side by side",
        f"Success on the protocol's {protocol.num_starts} test starts, in percent: the paper's Table 2; "
        "bfc's own regime (docs/report/table2: bfc's PPO settings, reward and observation, 2M frames, three "
        "seeds); the paper's regime (this sweep: +preset=paper, the final policy of each run, mean over its seeds).",
        "",
        "| variant | the paper | bfc's regime | the paper's regime | seeds, frames (paper's regime) |",
        "|---|---|---|---|---|",
    ]
    for variant in TABLE2_ORDER:
        paper = f"{PAPER_TABLE2[variant]:g}" if variant in PAPER_TABLE2 else "no policy"
        here = by_variant.get(variant, [])
        cell = mean_spread([r.get("test", {}).get("protocol") for r in here]) if here else "not run"
        trained = ", ".join(f"{int(r.get('frames', 0)) / 1e6:.1f}M" for r in here)
        seeds = f"{len(here)}: {trained}" if here else ""
        lines.append(f"| {variant} | {paper} | {_pct(bfc.get(variant))} | {cell} | {seeds} |")
    lines += [
        "",
        "## The paper's claims",
        "",
        "| claim | the paper | the paper's regime (this sweep) | bfc's regime | what bfc changed that moves it |",
        "|---|---|---|---|---|",
        *("| " + " | ".join(row) + " |" for row in claims(regime, bfc, algos, by_variant)),
        "",
        CLAIM_RULES,
        "",
    ]
    lines += runs_sections(dirs, out, protocol, by_variant=by_variant)
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
