import json

import pytest

from torchtof.adaptive import choose_method, load_table, save_table

TABLE = [
    {"n": 32, "sr": 0.125, "method": "PINV", "budget": None, "time_s": 1e-4, "psnr": 10.0,
     "depth_rmse_m": 0.4},
    {"n": 32, "sr": 0.125, "method": "TVAL3", "budget": 10, "time_s": 5e-3, "psnr": 12.0,
     "depth_rmse_m": 0.3},
    {"n": 32, "sr": 0.125, "method": "TVAL3", "budget": None, "time_s": 3e-2, "psnr": 13.0,
     "depth_rmse_m": 0.2},
    {"n": 32, "sr": 0.125, "method": "DIP", "budget": 100, "time_s": 1.0, "psnr": 15.0,
     "depth_rmse_m": 0.25},
    {"n": 64, "sr": 0.25, "method": "PINV", "budget": None, "time_s": 1e-4, "psnr": 20.0},
]


def test_time_budget_picks_the_most_accurate_that_fits():
    c = choose_method(32, 0.125, time_budget_s=0.01, table=TABLE)
    assert (c.method, c.n_iter, c.met) == ("TVAL3", 10, True)
    c = choose_method(32, 0.125, time_budget_s=1e-6, table=TABLE)
    assert c.method == "PINV" and not c.met


def test_target_picks_the_fastest_that_meets_it():
    assert choose_method(32, 0.125, target_psnr=12.5, table=TABLE).n_iter is None
    c = choose_method(32, 0.125, target_psnr=14.0, table=TABLE)
    assert c.method == "DIP" and c.met
    c = choose_method(32, 0.125, target_psnr=99.0, table=TABLE)
    assert c.method == "DIP" and not c.met
    c = choose_method(32, 0.125, target_depth_rmse_m=0.26, table=TABLE)
    assert (c.method, c.n_iter) == ("TVAL3", None)
    c = choose_method(32, 0.125, target_psnr=14.0, time_budget_s=0.1, table=TABLE)
    assert c.method == "TVAL3" and not c.met


def test_nearest_n_and_sr():
    assert choose_method(60, 0.3, time_budget_s=1.0, table=TABLE).psnr == 20.0
    assert choose_method(32, 0.1, time_budget_s=1.0, table=TABLE, methods=("PINV",)).psnr == 10


def test_shipped_table_and_round_trip(tmp_path):
    rows = load_table()
    assert {"PINV", "TVAL3", "DIP"} <= {r["method"] for r in rows}
    assert {32, 64} <= {r["n"] for r in rows}
    src = tmp_path / "bench.json"
    src.write_text(json.dumps({"points": TABLE, "rows": []}))
    dst = save_table(src, tmp_path / "t.json")
    assert load_table(dst) == [{k: r.get(k) for k in
                                ("n", "sr", "method", "budget", "label", "time_s", "psnr", "ssim",
                                 "depth_rmse_m")} for r in TABLE]
    assert choose_method(32, 0.125, time_budget_s=0.01, table=dst).method == "TVAL3"


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="time_budget_s"):
        choose_method(32, 0.125, table=TABLE)
    with pytest.raises(ValueError, match="time_budget_s > 0"):
        choose_method(32, 0.125, time_budget_s=0.0, table=TABLE)
    with pytest.raises(ValueError, match="sr"):
        choose_method(32, 1.5, time_budget_s=1.0, table=TABLE)
    with pytest.raises(ValueError, match="methods"):
        choose_method(32, 0.125, time_budget_s=1.0, table=TABLE, methods=("Nope",))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"n": 32}]))
    with pytest.raises(ValueError, match="keys"):
        load_table(bad)
