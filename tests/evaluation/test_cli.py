"""evaluate.py on the shipped policy, and its clean failures."""

import json

import torch

from bfc.agent import read_policy
from bfc.evaluation import fly, protocol_starts, success
from tests.evaluation.scripts import SHIPPED, evaluate


def test_shipped_policy_is_data_and_flies_at_its_own_rate():
    hz = read_policy(SHIPPED).spec.control_hz  # a weights_only load
    tr = fly(SHIPPED, protocol_starts(20, seed=0), seconds=10.0)
    assert tr.shape == (20, round(10.0 * hz))
    assert success(tr).float().mean() >= 0.9  # the shipped policy clears the paper's 90.5% here too


def test_evaluate_writes_results_and_figures(tmp_path):
    r = evaluate(f"policy={SHIPPED}", "eval.num_starts=12", out=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["starts"] == 12 and len(results["per_start"]) == 12
    assert results["success"] + results["fail"] == 12
    assert 0.0 <= results["success_rate"] <= 1.0
    for name in ("flight_1.png", "flights_10.png", "flights_all.png", "errors.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_missing_policy_fails_cleanly(tmp_path):
    r = evaluate("policy=/nonexistent/policy.pt", out=tmp_path)
    assert r.returncode == 2 and "no policy file at /nonexistent/policy.pt" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_checkpoint_is_not_a_policy(tmp_path):
    fake = tmp_path / "last.pt"
    torch.save({"frames": 3, "actor": {}}, fake)
    r = evaluate(f"policy={fake}", out=tmp_path / "run")
    assert r.returncode == 2 and "not a bfc policy file" in r.stderr


def test_unknown_controller_fails_cleanly(tmp_path):
    r = evaluate("controller=pid", out=tmp_path)
    assert r.returncode == 2 and "unknown controller 'pid'" in r.stderr


def test_paper_suite_writes_a_report_with_figures(tmp_path):
    r = evaluate("suite=paper", f"policy={SHIPPED}", "eval.num_starts=6", "eval.seconds=4", out=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    report = (tmp_path / "report.md").read_text()
    for section in ("## Protocol", "## Accuracy", "## Odometry noise", "## Waypoints", "## Controllers"):
        assert section in report
    # the baselines flew the same starts: one row each in the comparison, beside the policy
    for name in ("bfc", "mpc", "lee"):
        assert sum(line.startswith(f"| {name} | ") for line in report.splitlines()) == 1, name
    assert report.count("| gaussian") == 6 and report.count("| ou 0.05") == 2
    for name in ("noise.png", "waypoints_sparse.png", "waypoints_dense.png", "errors.png", "controllers_tilt.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_suite_reads_table_2_from_training_runs(tmp_path):
    from bfc.config import TestProtocolConfig
    from bfc.evaluation.report import runs_sections
    from bfc.training import train

    from ..training.helpers import TINY, compose_cfg

    for variant in ("jd_tdts", "jd"):
        train(compose_cfg([f"+ablation={variant}", *TINY, "env.episode_seconds=0.2"]), tmp_path / "runs" / variant)
    lines = runs_sections(tmp_path / "runs", tmp_path, TestProtocolConfig(num_starts=4, seconds=1.0))
    rows = [line for line in lines if line.startswith("| jd")]
    assert [row.split("|")[1].strip() for row in rows] == ["jd", "jd_tdts"]  # the paper's order
    assert (tmp_path / "learning_curves.png").stat().st_size > 10_000


def _fake_run(run_dir, variant: str, seed: int, policy, final: float, reached_at):
    import shutil

    import yaml

    run_dir.mkdir(parents=True)
    cfg = {"variant": variant, "seed": seed, "algo": {"name": "ppo"}, "collector": {"total_frames": 2_000_000}}
    (run_dir / "config.yaml").write_text(yaml.safe_dump(cfg))
    history = [{"frames": f, "wall_seconds": f / 1e4, "eval/success_rate": final} for f in (0, 1_000_000, 2_000_000)]
    reach = None if reached_at is None else {"frames": reached_at, "wall_seconds": 1.0}
    summary = {"final_success_rate": final, "best_success_rate": max(final, 0.5), "history": history}
    (run_dir / "summary.json").write_text(json.dumps({**summary, "first_reached_0.905": reach}))
    shutil.copy(policy, run_dir / "policy_last.pt")


def test_table_2_gives_the_mean_and_spread_of_the_final_policies_on_the_test_starts(tmp_path):
    from bfc.agent import save_policy
    from bfc.config import TestProtocolConfig
    from bfc.evaluation.report import runs_sections
    from bfc.evaluation.suites import START_SETS, score

    shipped = read_policy(SHIPPED)
    falling = tmp_path / "falling.pt"  # a policy that commands the motors off: never succeeds
    net = shipped.spec.make_net()
    with torch.no_grad():
        net.mlp[-1].bias.fill_(-1.0)
    save_policy(falling, shipped.spec, net)
    runs = tmp_path / "runs"
    _fake_run(runs / "a", "jd_css_tdts", 0, SHIPPED, 1.0, 1_000_000)
    _fake_run(runs / "b", "jd_css_tdts", 1, falling, 0.5, None)
    _fake_run(runs / "c", "ppo", 0, falling, 0.0, None)
    protocol = TestProtocolConfig(num_starts=8, seconds=3.0)
    lines = runs_sections(runs, tmp_path, protocol)
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
        for line in lines
        if "| 2,000,000 |" in line
    }
    assert list(rows) == ["ppo", "jd_css_tdts"]  # the paper's order
    expected = {}
    for name in ("protocol", "ground", "any"):
        flights = fly(SHIPPED, START_SETS[name](8, protocol.seed), seconds=3.0, seed=protocol.seed)
        expected[name] = 100 * score(flights)["success_rate"]
    assert expected["protocol"] > 0
    for k, name in enumerate(("protocol", "ground", "any")):
        sd = torch.tensor([expected[name], 0.0], dtype=torch.float64).std().item()  # sample std over the seeds
        mean = expected[name] / 2  # seeds: the shipped policy and a falling one
        assert rows["jd_css_tdts"][2 + k] == f"{mean:.1f} +- {sd:.1f} ({expected[name]:.0f}, 0)"
        assert rows["ppo"][2 + k] == "0.0 +- 0.0 (0)"
    assert rows["jd_css_tdts"][5] == "75.0 +- 35.4 (100, 50)"  # the validation columns: from the summaries
    assert rows["jd_css_tdts"][7] == "1.0M, never"
    saved = json.loads((tmp_path / "table2.json").read_text())
    assert saved["jd_css_tdts"][1]["test"]["protocol"] == 0.0


def test_the_protocol_keys_moved_under_eval(tmp_path):
    r = evaluate("policy=pretrained/policy.pt", "num_starts=5", out=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "error: num_starts has moved: it is eval.num_starts now"


def test_single_evaluation_honours_the_protocol_keys(tmp_path):
    r = evaluate(
        f"policy={SHIPPED}", "eval.num_starts=3", "eval.seconds=2", "eval.seed=7", "figures=false", out=tmp_path
    )
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["starts"] == 3 and results["protocol"]["seconds"] == 2.0 and results["protocol"]["seed"] == 7
    assert not (tmp_path / "flight_1.png").exists()


def test_a_controller_flies_the_airframe_it_is_given(tmp_path):
    r = evaluate(
        "controller=lee", "airframe=crazyflie", "eval.num_starts=4", "eval.seconds=8", "figures=false", out=tmp_path
    )
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["airframe"] == "crazyflie" and results["success"] == 4  # its tuned gains (slower: position x0.5)
    r = evaluate(f"policy={SHIPPED}", "airframe=crazyflie", out=tmp_path / "policy")
    assert r.returncode == 2 and "flies the airframe it was trained on (hummingbird)" in r.stderr
    assert "Traceback" not in r.stderr
