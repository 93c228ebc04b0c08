"""The paper's regime report (bfc.evaluation.regime) on a small fake sweep: the side-by-side
Table 2, the run states (a paused run says so) and each claim's verdict from the numbers."""

import json

import torch

from bfc.agent import read_policy, save_policy
from bfc.config import TestProtocolConfig as Protocol
from bfc.evaluation import fly
from bfc.evaluation.regime import write_regime_report
from bfc.evaluation.suites import START_SETS, score

from .scripts import SHIPPED
from .test_cli import _fake_run


def test_regime_report_on_a_fake_sweep(tmp_path):
    shipped = read_policy(SHIPPED)
    falling = tmp_path / "falling.pt"  # the motors off: never succeeds
    net = shipped.spec.make_net()
    with torch.no_grad():
        net.mlp[-1].bias.fill_(-1.0)
    save_policy(falling, shipped.spec, net)
    sweep, nojd = tmp_path / "sweep", tmp_path / "nojd"
    _fake_run(sweep / "a", "jd_css_tdts", 0, SHIPPED, 1.0, 1_000_000)
    _fake_run(sweep / "b", "jd_css_tdts", 1, falling, 0.0, None)
    _fake_run(sweep / "c", "jd", 0, SHIPPED, 1.0, 1_000_000)
    for name, variant in (("d", "jd_css"), ("e", "jd_tdts"), ("f", "ppo")):
        _fake_run(sweep / name, variant, 0, falling, 0.0, None)
    _fake_run(nojd / "g", "css", 0, falling, 0.0, None)
    summary = json.loads((sweep / "f" / "summary.json").read_text())
    (sweep / "f" / "summary.json").write_text(json.dumps({**summary, "frames": 1_000_448, "paused": True}))
    bfc = tmp_path / "bfc_table2.json"  # bfc's regime: plain PPO flies
    bfc.write_text(json.dumps({v: [{"test": {"protocol": r}}] for v, r in (("ppo", 0.9), ("jd", 0.95))}))
    protocol = Protocol(num_starts=6, seconds=3.0)
    report = write_regime_report([sweep, nojd], tmp_path / "out", bfc_table2=bfc, protocol=protocol).read_text()

    flights = fly(SHIPPED, START_SETS["protocol"](6, protocol.seed), seconds=3.0, seed=protocol.seed)
    s = 100 * score(flights)["success_rate"]
    assert s >= 50

    def table(section):  # {first cell: the other cells} of the table under the `## section` heading
        text = report.split(f"## {section}\n", 1)[1].split("\n## ", 1)[0]
        lines = [line for line in text.splitlines() if line.startswith("| ")]
        return {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in lines}

    rows = table("Table 2 side by side")
    # side by side: the paper's figure, bfc's regime, this sweep (mean +- sd (seeds)), seeds and frames
    assert rows["jd_css_tdts"][:2] == ["90.5", "n/a"]
    sd = torch.tensor([s, 0.0], dtype=torch.float64).std().item()
    assert rows["jd_css_tdts"][2] == f"{s / 2:.1f} +- {sd:.1f} ({s:.0f}, 0)"
    assert rows["jd_css_tdts"][3] == "2: 2.0M, 2.0M"
    assert rows["ppo"][:3] == ["no policy", "90.0", "0.0 +- 0.0 (0)"] and rows["ppo"][3] == "1: 1.0M"
    assert rows["tdts"][2] == "not run"
    assert "7 runs, 13.0M frames" in report and "1 of them paused" in report
    assert "| ppo | 0 | 1,000,448 | 2,000,000 | paused |" in report
    # each claim's verdict, from the numbers
    rows = table("The paper's claims")
    assert rows["JD is necessary: without it no variant learns"][1] == (
        f"holds (best without JD ppo 0.0, best with JD jd {s:.1f})"
    )
    assert rows["JD is necessary: without it no variant learns"][2].startswith(
        "does not hold (best without JD ppo 90.0"
    )
    assert rows["BFC > JD-CSS > JD-TDTS > JD"][1].startswith("does not hold (jd_css_tdts")
    assert rows["enhanced PPO beats enhanced TRPO"][1] == "not measured"
    assert rows["plain DDPG, TRPO and PPO do not learn"][1] == "holds (ppo 0.0); trpo, ddpg not run"
    assert (tmp_path / "out" / "learning_curves.png").stat().st_size > 10_000
    saved = json.loads((tmp_path / "out" / "table2.json").read_text())
    assert saved["css"][0]["test"]["protocol"] == 0.0


def test_each_claims_verdict_follows_its_rule():
    """Every branch of the claims' rules on hand-made means (success of the final policies)."""
    from bfc.evaluation.regime import claims

    def verdicts(means):
        return [row[2].split(" (")[0] for row in claims(means, {}, {})]

    jd = {"jd_css_tdts": 0.9, "jd_css": 0.6, "jd_tdts": 0.3, "jd": 0.2}
    assert verdicts({**jd, "ppo": 0.0, "css": 0.05}) == ["holds", "holds", "not measured", "holds"]
    assert verdicts({**jd, "ppo": 0.7}) == ["does not hold", "holds", "not measured", "does not hold"]
    partly = {"jd_css_tdts": 0.05, "jd_css": 0.3, "jd_tdts": 0.0, "jd": 0.0, "ppo": 0.2}
    assert verdicts(partly) == ["undecided", "does not hold", "not measured", "undecided"]
    nothing = {v: 0.0 for v in ("jd_css_tdts", "jd_css", "jd_tdts", "jd", "ppo", "trpo jd_css_tdts")}
    assert verdicts(nothing) == ["undecided", "undecided: none learned", "undecided: neither learned", "holds"]
    trpo = {"jd_css_tdts": 0.9, "trpo jd_css_tdts": 0.95, "ppo": 0.0, "trpo ppo": 0.8}
    assert verdicts(trpo)[2:] == ["does not hold", "holds in part"]
    assert verdicts({"jd": 0.9}) == ["not measured"] * 4


def test_an_undecided_verdict_says_what_would_decide_it():
    """The paper's regime's undecided verdicts name the frames that would decide them: those left
    in paused runs; else more seeds of a variant whose seeds split; else a longer schedule."""
    from bfc.evaluation.regime import claims

    def run(rate, frames=20_000_000, paused=False):
        return {"schedule_frames": 20_000_000, "frames": frames, "paused": paused, "test": {"protocol": rate}}

    runs = {v: [run(0.0)] for v in ("jd_css_tdts", "jd_css", "jd_tdts", "jd", "css")}
    runs["ppo"] = [run(0.49), run(0.07), run(0.0)]
    means = {v: sum(r["test"]["protocol"] for r in rs) / len(rs) for v, rs in runs.items()}
    rows = claims(means, {}, {}, runs)
    necessary, ordered, _, plain = (row[2] for row in rows)
    assert necessary.startswith("undecided (best without JD ppo 18.7, best with JD jd 0.0)")
    split = "ppo learns partly (seeds 49, 7, 0): more seeds of it, 20M frames each, decide it"
    assert necessary.endswith(f"; {split}")
    ended = "every run ended its 20M-frame schedule unlearned: only a longer schedule could decide it"
    assert ordered.endswith(f"; {ended}")
    assert plain == f"undecided (ppo 18.7); {split}; trpo, ddpg not run"
    runs["jd"] = [run(0.0, frames=2_000_000, paused=True)]
    assert claims(means, {}, {}, runs)[1][2].endswith("; 18.0M frames left in paused runs decide it")
    assert claims(means, {}, {})[0][2] == necessary.split(";")[0]  # bfc's regime (no runs given): no more


def test_finished_runs_are_kept_and_the_report_rebuilds_from_them_alone(tmp_path):
    """What the report reads of each finished run is copied into the repository (its summary and
    validation curve, config, final policy, episode returns from its TensorBoard events); a paused
    run stays in its sweep; with the sweep gone the report is written from the kept runs."""
    import shutil

    from torch.utils.tensorboard import SummaryWriter

    from bfc.evaluation.regime import keep_finished_runs

    sweep = tmp_path / "multirun" / "paper_regime"
    _fake_run(sweep / "jd_css_tdts" / "seed0_0", "jd_css_tdts", 0, SHIPPED, 1.0, 1_000_000)
    _fake_run(sweep / "ppo" / "seed0_1", "ppo", 0, SHIPPED, 1.0, None)
    paused = sweep / "ppo" / "seed0_1" / "summary.json"
    paused.write_text(json.dumps({**json.loads(paused.read_text()), "paused": True}))
    with SummaryWriter(str(sweep / "jd_css_tdts" / "seed0_0" / "tb")) as writer:
        for frames, value in ((8192, -3.0), (16384, -1.5)):
            writer.add_scalar("train/episode_return", value, frames)
    kept = keep_finished_runs([sweep], tmp_path / "runs")
    assert [k.name for k in kept] == ["jd_css_tdts_seed0"]
    run = kept[0]
    assert sorted(p.name for p in run.iterdir()) == ["config.yaml", "policy_last.pt", "scalars.json", "summary.json"]
    assert json.loads((run / "scalars.json").read_text()) == {"train/episode_return": [[8192, -3.0], [16384, -1.5]]}
    assert json.loads((run / "summary.json").read_text())["history"][-1]["frames"] == 2_000_000

    shutil.rmtree(tmp_path / "multirun")
    protocol = Protocol(num_starts=4, seconds=3.0)
    report = write_regime_report([tmp_path / "runs"], tmp_path / "out", protocol=protocol).read_text()
    assert "1 runs, 2.0M frames" in report and "| jd_css_tdts | 0 | 2,000,000 | 2,000,000 | finished |" in report
    assert (tmp_path / "out" / "learning_curves.png").stat().st_size > 10_000


def test_the_kept_runs_are_committed_not_ignored():
    """docs/report/paper_regime/runs/ is results the report rebuilds from on a fresh clone: git
    must track it (a `runs/` ignore rule once kept every kept run out of the repository)."""
    import shutil
    import subprocess
    from pathlib import Path

    import pytest

    root = Path(__file__).resolve().parents[2]
    if shutil.which("git") is None or not (root / ".git").exists():
        pytest.skip("not a git checkout")
    kept = root / "docs" / "report" / "paper_regime" / "runs"
    probe = [str(kept / "some_variant_seed0" / name) for name in ("summary.json", "policy_last.pt")]
    ignored = subprocess.run(["git", "check-ignore", *probe], cwd=root, capture_output=True, text=True)
    assert ignored.returncode == 1 and not ignored.stdout, ignored.stdout
