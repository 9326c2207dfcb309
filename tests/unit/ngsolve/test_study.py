"""The ngsolve study kind: schema, config, the benchmark module and a tiny Snakemake run."""
from __future__ import annotations

import csv

import pytest
import yaml

pytest.importorskip("ngsolve")

from conftest import ROOT, copy_workflow, run_snakemake
from ddstudies.ngsolve_bench import Row, run_study, summary
from ddstudies.workflow import SCHEMAS, ConfigError, validate

SCHEMA = ROOT / "workflows" / "schemas" / "ngsolve.schema.yaml"


def test_config_validates_and_schema_is_closed():
    config = yaml.safe_load((ROOT / "config" / "ngsolve.yaml").read_text())
    assert SCHEMAS[config["kind"]] == "ngsolve"
    validate(config, SCHEMA)
    assert [o["order"] for o in config["orders"]] == [1, 2, 3, 4]
    assert all(len(o["ndofs"]) == 3 and max(o["ndofs"]) == 1_000_000 for o in config["orders"])
    with pytest.raises(ConfigError, match="extra"):
        validate({**config, "extra": 1}, SCHEMA)
    with pytest.raises(ConfigError, match="solvers/0"):
        validate({**config, "solvers": ["umfpack"]}, SCHEMA)
    assert [b["pattern"] for b in config["scaling_study"]] == ["stripes", "checker"]
    with pytest.raises(ConfigError, match="scaling_study/0"):
        validate({**config, "scaling_study": [{"pattern": "spots", "orders": [1], "maxh": [0.1], "parts": [4]}]},
                 SCHEMA)
    assert [o["order"] for o in config["cube"]["orders"]] == [1, 2, 3]
    with pytest.raises(ConfigError, match="cube"):
        validate({**config, "cube": {"orders": [{"order": 1, "ndofs": [1000]}], "maxh": 0.1}}, SCHEMA)


def test_small_study_agrees_with_the_direct_solution():
    rows = run_study({"orders": [{"order": 2, "ndofs": [3000]}], "dofs_per_part": 500, "rtol": 1e-10,
                      "maxiter": 200, "solvers": ["ddinverse-bddc", "ddinverse-fetidp", "ngs-bddc-cg",
                                                  "sparsecholesky"]})
    by = {r.solver: r for r in rows}
    assert set(by) == {"ddinverse-bddc", "ddinverse-fetidp", "ngs-bddc-cg", "sparsecholesky"}
    for name in ("ddinverse-bddc", "ddinverse-fetidp"):
        assert by[name].relerr < 1e-8 and by[name].iterations > 0 and by[name].parts >= 5
    assert "order 2" in summary(rows) and "NGSolve bddc+CG" in summary(rows)


def test_summary_targets():
    rows = [Row("ddinverse-bddc", 1, 100, 4, 1.0, 1.0, 2.0, 10, 0.0, 0.5),
            Row("sparsecholesky", 1, 100, 0, 3.0, 2.0, 5.0, 0, 0.0, 0.5),
            Row("ddinverse-bddc-sweep", 1, 100, 64, 1, 1, 2, 20, float("nan"), 0.5),
            Row("ddinverse-bddc-sweep", 1, 100, 1024, 1, 1, 2, 27, float("nan"), 0.5)]
    text = summary(rows)
    assert "= 0.40 (target <= 0.5: met)" in text
    assert "20 -> 27 (1.35x; target <= 1.3x: NOT met)" in text


def test_workflow_runs_the_study(tmp_path):
    copy_workflow(tmp_path)
    cfg = {"kind": "ngsolve", "study": "ngs_tiny", "orders": [{"order": 1, "ndofs": [1500]}],
           "solvers": ["ddinverse-bddc", "sparsecholesky"], "dofs_per_part": 300,
           "scaling_study": [{"pattern": "stripes", "orders": [1], "maxh": [0.1], "parts": [6]}],
           "cube": {"orders": [{"order": 1, "ndofs": [800]}], "solvers": ["ddinverse-fetidp", "sparsecholesky"]}}
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(cfg))
    run_snakemake(tmp_path, "--cores", "1", "--configfile", "tiny.yaml", timeout=600)
    with open(tmp_path / "results" / "ngs_tiny" / "ngsolve.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["solver"] for r in rows] == ["ddinverse-bddc", "sparsecholesky"]
    assert float(rows[0]["relerr"]) < 1e-6
    assert (tmp_path / "reports" / "ngs_tiny" / "ngsolve.png").stat().st_size > 1000
    report = (tmp_path / "reports" / "ngs_tiny" / "ngsolve.md").read_text()
    assert "## Scaling where METIS parts cut coefficient jumps" in report and "| 1 | 0.1 |" in report
    assert "## 3D: the same problem on the unit cube" in report and "| ddinverse-fetidp | 1 |" in report
    # the HTML report holds the table and the plot (it had none of the study's items: a review)
    run_snakemake(tmp_path, "--cores", "1", "--configfile", "tiny.yaml", "--report", "report.html", timeout=600)
    html = (tmp_path / "report.html").read_text(errors="replace")
    assert "one panel per polynomial order" in html and "all timed in one job" in html    # the captions


def test_cube_study_agrees_with_the_direct_solution():
    from ddstudies.ngsolve_bench import cube_study, cube_table, make_cube_mesh

    assert make_cube_mesh(1, 2000).dim == 3
    rows = cube_study({"orders": [{"order": 1, "ndofs": [1500]}, {"order": 2, "ndofs": [3000]}],
                       "solvers": ["ddinverse-bddc", "ddinverse-fetidp", "ddinverse-fetidp-edges", "ngs-bddc-cg",
                                   "sparsecholesky"]},
                      {"dofs_per_part": 300, "rtol": 1e-10, "maxiter": 200})
    assert [(r.solver, r.order) for r in rows][:5] == [("ddinverse-bddc", 1), ("ddinverse-fetidp", 1),
                                                       ("ddinverse-fetidp-edges", 1), ("ngs-bddc-cg", 1),
                                                       ("sparsecholesky", 1)]
    for r in rows:
        assert 700 < r.ndof < 6000 and r.error == ""
        if r.solver.startswith("ddinverse"):
            assert r.relerr < 1e-8 and 0 < r.iterations < 30 and r.parts >= 3
    table = cube_table(rows)
    assert table.count("(fastest of each)") == 2 and "| ddinverse-fetidp | 2 |" in table


def test_parts_sweep_table():
    from ddstudies.ngsolve_bench import parts_sweep, sweep_table

    rows = parts_sweep(1, 3000, [4, 16])
    assert [r.parts for r in rows] == [4, 16]
    assert all(0 < r.iterations < 40 for r in rows)
    table = sweep_table(rows)
    assert table.count("\n") == 4 and "| 1 | " in table
    # the study's parts_sweep rows carry the mesh's dofs, as parts_sweep's do (they read the requested 3000)
    from ddstudies.ngsolve_bench import run_study

    study = run_study({"orders": [], "parts_sweep": [{"order": 1, "ndof": 3000, "parts": [4]}], "rtol": 1e-8,
                       "maxiter": 200})
    assert [(r.solver, r.ndof, r.parts) for r in study] == [("ddinverse-bddc-sweep", rows[0].ndof, 4)]
    assert rows[0].ndof != 3000


def test_scaling_study_table():
    from ddstudies.ngsolve_bench import main, scaling_study, scaling_table

    rows = scaling_study([1], [0.1], [6], "stripes")
    assert len(rows) == 1 and rows[0]["ndof"] > 0
    assert rows[0]["deluxe_its"] <= rows[0]["diagonal_its"]
    table = scaling_table(rows, "stripes")
    assert table.count("\n") == 5 and "| 1 | 0.1 |" in table
    assert rows[0]["ngs_bddc_its"] > 0
    with pytest.raises(ValueError, match="pattern"):
        scaling_study([1], [0.2], [4], "spots")
    assert main(["--scaling-study", "1", "0.2", "4", "checker"]) == 0


@pytest.mark.parametrize("dim, maxh, primal", [(2, 0.2, "vertices"), (3, 0.5, "vertices"),
                                               (3, 0.5, "vertices+edges")])
def test_hh_study_refines_at_a_fixed_partition(dim, maxh, primal):
    """H/h doubles at a fixed coarse partition: the dofs grow by about 2^dim, the condition number grows
    slowly (polylogarithmic), and the fit is returned."""
    from ddstudies.ngsolve_bench import hh_study, hh_table

    out = hh_study(1, 4, (0, 1), maxh=maxh, dim=dim, primal=primal)
    growth = out["ndof"][1] / out["ndof"][0]
    assert 2 ** dim / 2 < growth < 2 ** dim * 2
    assert 1.0 < out["cond"][0] < out["cond"][1] < 4.0
    assert out["fit"]["c1"] > 0
    assert hh_table({1: out}, 4).count("\n") == 4
