"""The README is executable: every ```python block runs, in order, in one namespace (later
blocks may use names an earlier block defined, as a reader would), and names nothing that
does not ship."""

import re
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def _blocks() -> list[tuple[int, str]]:
    text = README.read_text(encoding="utf-8")
    return [(text[: m.start()].count("\n") + 1, m.group(1)) for m in BLOCK.finditer(text)]


def test_readme_has_python_snippets():
    assert len(_blocks()) >= 3


def test_every_readme_python_snippet_runs():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    namespace: dict = {"__name__": "__readme__"}
    try:
        for line, code in _blocks():
            try:
                exec(compile(code, f"README.md:{line}", "exec"), namespace)
            except Exception as exc:  # noqa: BLE001 - report which block failed
                pytest.fail(f"README.md python block at line {line} failed: "
                            f"{type(exc).__name__}: {exc}")
    finally:
        torch.set_num_threads(threads)


@pytest.mark.parametrize("name", ["DES" + "IGN.md", "STY" + "LE.md", "domain" + "-notes"])
def test_readme_cites_nothing_that_does_not_ship(name):
    assert name not in README.read_text(encoding="utf-8")


def _build():
    import importlib.util

    if "docs_build" in sys.modules:
        return sys.modules["docs_build"]
    path = README.parent / "docs" / "build.py"
    spec = importlib.util.spec_from_file_location("docs_build", path)
    build = importlib.util.module_from_spec(spec)
    sys.modules["docs_build"] = build  # dataclasses resolve their module by name
    spec.loader.exec_module(build)
    return build


def _generated_names() -> list[str]:
    text = README.read_text(encoding="utf-8")
    return re.findall(r"<!-- generated:([\w-]+) -->", text)


def test_every_build_target_has_one_readme_block_and_back():
    names = _generated_names()
    assert len(names) == len(set(names)), f"a generated block appears twice: {names}"
    assert sorted(names) == sorted(_build().SECTIONS), (
        "README generated blocks and docs/build.py targets differ")


@pytest.mark.parametrize("name", _generated_names())
def test_generated_readme_block_matches_its_json(name):
    build = _build()
    text = README.read_text(encoding="utf-8")
    assert name not in build.stale_blocks(text), (
        f"README block {name!r} drifted from {build.SECTIONS[name].json}: run python docs/build.py")
    # the check is not vacuous: one changed character in this block is caught
    m = re.search(rf"<!-- generated:{name} -->\n(.*?)<!-- /generated:{name} -->", text, re.S)
    assert m.group(1).strip(), f"README block {name!r} is empty"
    opening = f"<!-- generated:{name} -->\n"
    edited = text.replace(opening, opening + "| x |\n", 1)
    assert build.stale_blocks(edited) == [name]


def test_generated_blocks_state_the_load_where_they_state_seconds():
    build = _build()
    for name in _generated_names():
        body = build.render(name)
        if re.search(r"\d ms\b|\d s\b|time s", body):
            assert "load" in body or "load" in build.SECTIONS[name].note, name


# --- the renderers, on hand-made JSON whose right answer is worked out here -----------------
def _machine(a, b, threads=1):
    return {"start": {"load_1min": a, "cpus": 2, "threads": threads},
            "end": {"load_1min": b, "cpus": 2, "threads": threads}}


def test_load_is_stated_as_the_range_of_start_and_end():
    build = _build()
    assert build._load({"machine": _machine(1.01, 0.36)}) == "load 0.4–1.0 on 2 CPUs, 1 thread"
    assert build._load({"machine": _machine(2.0, 2.04, 2)}) == "load 2.0 on 2 CPUs, 2 threads"
    assert build._load({}) == "load not recorded"


def test_operators_speed_up_is_dense_over_the_auto_method():
    build = _build()
    rows = [{"n": 32, "N": 1024, "hadamard_auto": "matmul", "hadamard_matmul_s": 2.5e-4,
             "hadamard_kron_s": 5e-4, "hadamard_fwht_s": 1e-3, "best_hadamard_s": 2.5e-4,
             "dense_s": 1e-3, "pattern_operator_s": 2e-3}]
    text = build.render_operators({"batch": 16, "sr": 0.25, "torch": "t", "repeat": 5,
                                   "machine": _machine(1, 1), "rows": rows})
    # 1e-3 / 2.5e-4 = 4.0
    assert "| 32 | 0.250 ms (matmul) | 1.00 ms | 2.00 ms | 4.0× | – |" in text


def test_tradeoff_picks_the_best_psnr_within_each_budget():
    build = _build()
    rec = [{"n": 32, "budget_s": 1e-3, "method": "PINV", "psnr": 10.04, "time_s": 1e-4},
           {"n": 32, "budget_s": 1.0, "method": "TVAL3@80", "psnr": 13.6, "time_s": 0.12}]
    pts = [{"n": 32, "sr": 0.25, "label": "PINV", "method": "PINV", "psnr": 10.04,
            "time_s": 1e-4, "pareto": True},
           {"n": 32, "sr": 0.25, "label": "BP@20", "method": "BP", "psnr": 11.0,
            "time_s": 1e-2, "pareto": True},
           {"n": 32, "sr": 0.25, "label": "TVAL3@80", "method": "TVAL3", "psnr": 13.6,
            "time_s": 0.12, "pareto": True}]
    text = build.render_tradeoff({"recommend": rec, "points": pts, "scenes": ["sky"],
                                  "noise": 0.01, "quick": True, "total_s": 9.6,
                                  "torch": "t", "machine": _machine(3, 3)})
    assert "| 1 ms | PINV / g2 (10.0 dB, 100 µs) |" in text
    assert "| 1 s | TVAL3, 80 iterations (13.6 dB, 120 ms) |" in text
    assert "TVAL3, 80 iterations in 1 (13.6–13.6 dB" in text
    assert "BP on the Pareto front: n = 32, SR 25.00% (BP, 20 iterations)." in text


def test_unrolled_delta_and_the_within_half_a_db_count():
    build = _build()
    rows = [{"n": 32, "sr": 0.0625, "noise": 0.01, "unrolled_db": 17.0, "best_tval3": "auto",
             "best_tval3_db": 17.7, "time_ratio": 20.0, "cpu_time_ratio": 9.6},
            {"n": 64, "sr": 0.25, "noise": 0.01, "unrolled_db": 21.3, "best_tval3": "mu256",
             "best_tval3_db": 20.8, "time_ratio": 14.4, "cpu_time_ratio": 12.2}]
    text = build.render_unrolled({"rows": rows, "total_s": 60, "scenes": 23, "torch": "t",
                                  "machine": _machine(1, 1)})
    assert "| 32 | 6.25 % | 17.00 | 17.70 (μ auto) | −0.70 | 20× / 10× |" in text
    assert "| 64 | 25 % | 21.30 | 20.80 (μ 2⁸) | +0.50 | 14× / 12× |" in text
    assert "1 of 2 rows are within 0.5 dB" in text and "(worst -0.70 dB at n = 32" in text
    assert "takes 10× to 12× less CPU time per image" in text
    del rows[0]["cpu_time_ratio"]  # a run without CPU times: wall-clock ratios, said so
    text = build.render_unrolled({"rows": rows, "total_s": 60, "scenes": 23, "torch": "t",
                                  "machine": _machine(1, 1)})
    assert "| 20× / – |" in text and "takes 14× to 20× less wall-clock time" in text


def test_reproduce_counts_the_cells_each_method_wins():
    build = _build()
    psnr = {(0.0625, "CGI"): 8.0, (0.0625, "BP"): 7.5, (0.0625, "TVAL3"): 8.5,
            (0.0625, "DIP"): 9.0, (0.125, "CGI"): 8.5, (0.125, "BP"): 8.0,
            (0.125, "TVAL3"): 9.6, (0.125, "DIP"): 9.4}
    rows = [{"method": m, "sr": sr, "psnr": v} for (sr, m), v in psnr.items()]
    res = {"table": {"air": rows}, "raw": {"air": {"psnr": 6.5}}, "options": {}, "quick": True,
           "realisations": 2, "total_s": 70, "machine": _machine(1, 1), "claims": []}
    text = build.render_reproduce(res)
    assert "above in 1 of 2 (case, SR) cells" in text  # 9.0 > 8.5, 9.4 < 9.6
    assert "best of all methods in 1 of 2 cells (the others: TVAL3 1)" in text
    assert "TVAL3 ≥ CGI and BP at SR ≤ 12.5 %** in 2 of 2 cells" in text
    assert "CGI 8.50 dB at 12.5% (paper 8.23)" in text
    assert "raw ToF image 6.50 dB (paper 5.70)" in text


def test_a_block_inside_a_list_item_keeps_its_indentation():
    build = _build()
    text = "- item\n\n  <!-- generated:operators -->\n  <!-- /generated:operators -->\n"
    out, found = build.rewrite(text)
    assert found == ["operators"]
    body = out.split("<!-- generated:operators -->\n", 1)[1].split("  <!-- /generated")[0]
    lines = [ln for ln in body.splitlines() if ln.strip()]
    assert lines and all(ln.startswith("  ") for ln in lines), body
    assert build.stale_blocks(out) == []
    assert build.stale_blocks(out.replace("\n  | 32 |", "\n| 32 |", 1)) == ["operators"]


def test_run_times_each_target_records_its_load_and_survives_a_failing_one(
        tmp_path, monkeypatch, capsys):
    import json

    build = _build()
    # sleeps 0.2 s so that its time, recorded to 0.1 s, cannot round to 0
    ok = (sys.executable, "-c", "import json, os, time; time.sleep(0.2); "
          "open('ok.json', 'w').write(json.dumps("
          "{'v': 3, 'path': os.environ['PYTHONPATH']}))")
    sections = {"ok": build.Section("ok.json", lambda d: f"value {d['v']}", ok),
                "bad": build.Section("bad.json", str, (sys.executable, "-c",
                                                       "raise SystemExit(3)"))}
    readme = tmp_path / "README.md"
    readme.write_text("x\n<!-- generated:ok -->\n<!-- /generated:ok -->\n", encoding="utf-8")
    for name, value in (("ROOT", tmp_path), ("README", readme), ("SECTIONS", sections),
                        ("TIMES", tmp_path / "times.json")):
        monkeypatch.setattr(build, name, value)
    assert build.main(["--run"]) == 1  # "bad" failed, "ok" still ran and was rendered
    assert "<!-- generated:ok -->\nvalue 3\n<!-- /generated:ok -->" in readme.read_text()
    out = capsys.readouterr()
    assert "[docs] time per target: ok " in out.out and "FAILED: bad" in out.out
    assert "bad: FAILED with exit status 3" in out.err
    times = json.loads((tmp_path / "times.json").read_text())
    assert set(times) == {"ok"} and times["ok"]["seconds"] > 0
    # the commands import the checkout's torchtof, not whatever is installed
    path = json.loads((tmp_path / "ok.json").read_text())["path"]
    assert path.split(__import__("os").pathsep)[0] == str(tmp_path)
    assert times["ok"]["start"]["cpus"] >= 1 and "load_1min" in times["ok"]["end"]


def test_bad_inputs_sums_only_the_modules_the_sentence_names():
    build = _build()
    zero = dict.fromkeys(("clear", "correct", "silent-wrong", "cryptic", "crash"), 0)
    res = {"calls": 3, "modules": ["operators", "sensor"], "classes": list(zero),
           "counts": {"operators": {**zero, "clear": 10, "correct": 4},
                      "sensor": {**zero, "clear": 5, "cryptic": 1},
                      "recon": {**zero, "clear": 100, "crash": 7}},  # outside: not counted
           "torch": "t", "command": "python -m tests.reliability.matrix --out x.json"}
    text = build.render_bad_inputs(res)
    # 10 + 4 + 5 + 1 = 20 cases, 15 clear, 4 correct, 1 cryptic, recon left out
    assert "misuses 3 public calls" in text and "of 20 cases, 15 are refused clearly and 4 " \
        "answered correctly — 0 silent-wrong, 1 cryptic, 0 crash" in text


def test_fault_sweep_states_counts_time_and_load_from_its_json():
    build = _build()
    mode = {"runs": 6328, "singles": 112, "doubles": 6216}
    res = {"setup": {"kinds": ["drop", "stall"], "positions": 16}, "modes": {"device": mode},
           "runs": 12656, "wrong_buckets": 1, "failed_runs": 2, "wall_s": 2220.6,
           "cpu_s": 1570.2, "workers": 2, "cores": 2, "load_avg_start": [7.06, 3.6, 2.5],
           "load_avg_end": [17.58, 14.9, 12.7], "torch": "t", "date_utc": "2026-11-25T15:38Z",
           "command": "python benchmarks/fault_sweep.py --workers 2"}
    text = build.render_fault_sweep(res)
    assert "(lost, stalled: 2 kinds × 16 frames" in text and "pair of them (6 216)" in text
    assert "**12 656 runs, 1 wrong buckets, 2 failed runs**" in text
    # 2220.6 s = 37.0 min, 1570.2 s = 26.2 min; loads 7.06 and 17.58
    assert "37 min wall, 26 min CPU" in text and "load average 7–18" in text


def test_run_prints_a_render_only_command_instead_of_running_it(tmp_path, monkeypatch, capsys):
    build = _build()
    marker = tmp_path / "ran"
    sec = build.Section("x.json", lambda d: f"v {d['v']}",
                        (sys.executable, "-c", f"open({str(marker)!r}, 'w')"),
                        render_only="2 h here")
    (tmp_path / "x.json").write_text('{"v": 7}', encoding="utf-8")
    readme = tmp_path / "README.md"
    readme.write_text("<!-- generated:x -->\n<!-- /generated:x -->\n", encoding="utf-8")
    for name, value in (("ROOT", tmp_path), ("README", readme), ("SECTIONS", {"x": sec}),
                        ("TIMES", tmp_path / "times.json")):
        monkeypatch.setattr(build, name, value)
    assert build.main(["--run", "x"]) == 0
    assert not marker.exists()
    assert "x: not rerun here (2 h here)" in capsys.readouterr().out
    assert "<!-- generated:x -->\nv 7\n" in readme.read_text()


def test_learned_means_minima_and_time_ratios_are_worked_out_from_the_rows():
    build = _build()

    def row(n, sr, level, cls, learned, tval3, t_l=0.01, t_t=0.2):
        return {"n": n, "sr": sr, "level": level, "class": cls, "learned": [learned, 0.5],
                "tval3": [tval3, 0.4], "t_learned": t_l, "t_tval3": t_t}

    rows = [row(32, 0.125, 0.01, "depth", 20.0, 19.0),   # Δ +1.0, ratio 20
            row(32, 0.125, 0.01, "natural", 18.0, 19.0),  # Δ -1.0, ratio 20
            row(32, 0.25, 0.0, "depth", 25.0, 22.0, t_t=0.05),  # Δ +3.0, ratio 5
            row(256, 0.125, 0.0, "depth", 30.0, 29.5, t_l=1.0, t_t=0.8)]  # Δ +0.5, ratio 0.8
    res = {"rows": rows,
           "auto_rows": [{"n": 32, "sr": 0.125, "level": 0.01, "class": "depth",
                          "auto": [19.5, 0.4], "t_auto": 2.0}],
           "speed": [{"n": 32, "learned_ms": 15.2, "tval3_ms": 220.8, "ratio": 14.56,
                      "load_avg": 12.3}],
           "onnx": [{"n": 32, "batch": 8, "ort_ms": 5.01, "torch_ms": 14.64,
                     "max_abs_err": 6.6e-7}],
           "paper": [{"sr": 0.125, "gate": False, "learned": [10.6, 0.2],
                      "tval3": [9.9, 0.15]}]}
    text = build.render_learned(res)
    assert "| n = 32 | n = 256 (SR ≤ 12.5 % only) |" in text
    assert "| 0 % | +3.00 (min +3.00) | +0.50 (min +0.50) |" in text
    assert "| 1 % | +0.00 (min -1.00) | - |" in text  # (1 - 1) / 2
    assert "| 14.6× (221 / 15 ms) | - |" in text  # TVAL3 / learned, as the label
    assert "+0.50 dB at SR ≤ 12.5 %, 1 % noise (1 cells, n ≤ 32, min +0.50)" in text  # 20 - 19.5
    assert "10–10× a default TVAL3 solve per image on these cells" in text  # 2.0 / 0.2 s
    assert "at every SR, with and without the 3 m gate" in text
    assert "it is +0.00 dB from TVAL3's defaults on average (2 cells" in text
    assert "worse in 1 of 3 (class, n, SR, noise) cells at n ≤ 128 (worst -1.00 dB: n = 32, " \
        "SR 12.5 %, 1 % noise natural)" in text
    # medians: n = 32 over 20, 20, 5 -> 20; n = 256: 0.8
    assert "20.0× at n = 32, 0.8× at n = 256" in text
    assert "below 10× on 1 of 1 noise-free cells at n ≤ 128 (down to 5.0×), 0.8–0.8×" in text


def test_export_time_is_dynamo_over_the_tracer_with_its_load():
    build = _build()
    rows = [{"model": "unrolled_tval3", "n": 32, "sr": 0.25, "n_iter": 12, "exporter": e,
             "export_s": s} for e, s in (("torchscript", 1.5), ("dynamo", 36.0))]
    text = build.render_export_time({"rows": rows, "machine": _machine(4.37, 5.37),
                                     "torch": "t", "command": "python x.py"})
    # 36.0 / 1.5 = 24
    assert ("unrolled TVAL3 (K = 12) at n = 32, SR 25 %: 36.0 s to export with dynamo against "
            "1.5 s with the TorchScript tracer (24×)") in text
    assert "load 4.4–5.4 on 2 CPUs, 1 thread" in text and "`python x.py`" in text


def test_learned_recipe_states_the_training_run_from_the_recipe():
    build = _build()
    rec = {"steps_run": 1300, "wall_s": 1712.0, "command": "torchtof train x", "world_size": 2,
           "threads": 1, "load_avg_end": [10.6, 10.7, 10.8], "torch_version": "t",
           "calibration_wall_s": 69.6, "calibration_command": "torchtof train y"}
    text = build.render_learned_recipe(rec)
    # 1712 s = 28.53 min; 69.6 s rounds to 70
    assert text.startswith("The shipped weights took 1300 steps in 28.5 min (`torchtof train "
                           "x`, 2 processes, 1 thread, 1-minute load 11 at the end, torch t)")
    assert "plus 70 s to calibrate the final step (`torchtof train y`)" in text
    del rec["calibration_command"]  # calibrated by the training command itself
    assert build.render_learned_recipe(rec).endswith(
        "plus 70 s to calibrate the final step at the end of the same command.")


def test_depth_joint_counts_wins_below_12_5_percent_and_lists_where_tval3_wins():
    build = _build()

    def row(scene, mp, sr, pinv, tval3, sep, joint, wins):
        return {"scene": scene, "multipath": mp, "sr": sr, "wins": wins, "realisations": 5,
                "pinv": pinv, "TVAL3": tval3, "vTV-sep": sep, "joint": joint}

    rows = [row("sky", "off", 0.0625, 0.08, 0.14, 0.105, 0.057, 5),
            row("slanted", "off", 0.125, 0.038, 0.045, 0.051, 0.047, 4),
            row("steps", "off", 0.25, 0.12, 0.083, 0.095, 0.093, 1)]  # SR 25 %: not counted
    res = {"command": "python b.py", "realisations": 5, "scenes": ["sky", "slanted", "steps"],
           "rows": rows, "summary": {"on": {"ratio": 0.9581}, "off": {"ratio": 0.8576}},
           "machine": _machine(0.9, 1.1)}
    text = build.render_depth_joint(res)
    assert "in 9 of 10 paired realisations" in text  # 5 + 4 of 5 + 5; the 25 % row left out
    assert "ratio 0.958 with multipath, 0.858 without" in text
    assert "joint 0.057 vs separate 0.105 m" in text
    assert "pseudo-inverse 0.038 vs joint 0.047 m" in text
    assert "beats joint at 25 % with multipath off (0.083 vs 0.093 m)." in text
    assert "load 0.9–1.1 on 2 CPUs, 1 thread" in text


def test_dip_time_states_the_median_span_the_range_and_the_load():
    build = _build()
    res = {"command": "python benchmarks/time_dip.py --iters 300 --repeats 3 --threads 2",
           "n": 32, "iters": 300, "repeats": 3,
           "rows": [{"sr": 0.0625, "iterations": 300, "walls_s": [2.3, 2.1, 2.5], "median_s": 2.3},
                    {"sr": 0.125, "iterations": 300, "walls_s": [2.4, 3.0, 2.2], "median_s": 2.4}],
           "machine": _machine(1.0, 1.2, threads=2)}
    text = build.render_dip_time(res)
    assert text.startswith("300 steps at 32×32 take 2.30–2.40 s (median of 3 per SR, "
                           "6.25 %, 12.5 %; range 2.10–3.00 s; load 1.0–1.2 on 2 CPUs, 2 threads)")


def test_threads_states_both_spans_in_their_units_and_the_load():
    build = _build()
    res = {"n": 32, "sr": 0.25, "noise": 0.01, "repeat": 5,
           "runs_s": {"1": [0.19, 0.24], "2": [2.1, 13.6]}, "machine": _machine(14.0, 14.04)}
    text = build.render_threads(res)
    assert "at load 14.0, TVAL3 defaults on n = 32, SR 25 %, median of 5" in text
    assert "**190–240 ms with one thread, 2.1–13.6 s with two**" in text
    assert "(2 runs each" in text
