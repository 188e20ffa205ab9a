"""Where the results store is when none is given (gimbal_lab.runner.default_store_root, the CLI's
--store), and how many local workers a sweep starts when it names none (default_jobs)."""

import os
from pathlib import Path

import pytest

from gimbal_lab import runner
from gimbal_lab.runner import JOBS_ENV, STORE_ENV, ResultsStore, checkout_root, default_jobs, default_store_root

ROOT = Path(__file__).resolve().parents[1]
EDITABLE = Path(runner.__file__).resolve().parents[1] == ROOT  # `pip install -e .` of this checkout
needs_checkout = pytest.mark.skipif(not EDITABLE, reason="gimbal_lab is not imported from this checkout "
                                                         "(not an editable install): no checkout to find")


@pytest.fixture(autouse=True)
def no_store_variable(monkeypatch):
    monkeypatch.delenv(STORE_ENV, raising=False)
    monkeypatch.delenv(JOBS_ENV, raising=False)


@needs_checkout
@pytest.mark.parametrize("where", [".", "notebooks", "gimbal_lab/studies"])
def test_inside_the_checkout_the_store_is_results_store_at_its_root(where, monkeypatch):
    """A notebook (run from notebooks/) and `gimbal-lab run paper --out results` run from the root
    find one store."""
    monkeypatch.chdir(ROOT / where)
    assert checkout_root() == ROOT
    assert default_store_root() == ROOT / "results" / "store"
    assert ResultsStore.default().root == ROOT / "results" / "store"


def test_outside_the_checkout_the_store_is_results_store_here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert checkout_root() is None
    assert default_store_root() == tmp_path / "results" / "store"


def test_the_variable_overrides_the_default(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(STORE_ENV, str(tmp_path / "elsewhere"))
    assert default_store_root() == tmp_path / "elsewhere"
    monkeypatch.setenv(STORE_ENV, "relative/store")  # taken from the current folder, made absolute
    assert default_store_root() == tmp_path / "relative" / "store"
    monkeypatch.setenv(STORE_ENV, "~/s")
    assert default_store_root() == Path.home() / "s"
    monkeypatch.setenv(STORE_ENV, "  ")  # blank: as if unset
    assert default_store_root() == tmp_path / "results" / "store"


def test_a_folder_that_is_not_this_projects_checkout_is_not_one(tmp_path, monkeypatch):
    """The package's parent folder counts only when its pyproject.toml names gimbal-lab."""
    package = tmp_path / "gimbal_lab"
    package.mkdir()
    monkeypatch.setattr(runner, "__file__", str(package / "runner.py"))
    monkeypatch.chdir(tmp_path)
    assert checkout_root() is None  # no pyproject.toml
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "something-else"\n')
    assert checkout_root() is None
    (tmp_path / "pyproject.toml").write_text("[project\n")  # unreadable
    assert checkout_root() is None
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "gimbal-lab"\n')
    assert checkout_root() == tmp_path
    monkeypatch.chdir(tmp_path.parent)  # outside it
    assert checkout_root() is None


def test_jobs_default_to_the_variable_or_the_cpu_count(monkeypatch):
    assert default_jobs() == os.cpu_count()
    monkeypatch.setenv(JOBS_ENV, " 3 ")
    assert default_jobs() == 3
    for bad in ("0", "-2", "two", "1.5"):
        monkeypatch.setenv(JOBS_ENV, bad)
        with pytest.raises(ValueError, match=f"GIMBAL_LAB_JOBS must be an integer >= 1 .*got '{bad}'"):
            default_jobs()


def test_a_sweep_without_jobs_starts_the_variables_number_of_workers(monkeypatch):
    """run(jobs=None) sizes its local pool by default_jobs (at most one worker per run), and runs in
    its own process when that is 1."""
    from gimbal_lab.studies import paper

    configs = paper.grid(paper.PaperStudy(replicates=2, period_s=0.3))[:3]

    class Sized(Exception):
        pass

    def pool(jobs):
        raise Sized(jobs)

    def in_this_process(config, source=None):
        raise Sized("in process")

    monkeypatch.setattr(runner, "_local_pool", pool)
    monkeypatch.setattr(runner, "_run_one", in_this_process)
    for value, expected in (("2", 2), ("5", 3), ("1", "in process")):
        monkeypatch.setenv(JOBS_ENV, value)
        with pytest.raises(Sized) as caught:
            runner.run(configs, progress=False)
        assert caught.value.args == (expected,)
    monkeypatch.setenv(JOBS_ENV, "2")
    with pytest.raises(Sized) as caught:
        runner.run(configs, jobs=1, progress=False)  # jobs given: the variable is not read
    assert caught.value.args == ("in process",)


@pytest.mark.parametrize("argv, env, expected", [
    (["--out", "{tmp}/out"], None, "{tmp}/out/store"),
    (["--out", "{tmp}/out"], "{tmp}/shared", "{tmp}/shared"),
    (["--out", "{tmp}/out", "--store", "{tmp}/mine"], "{tmp}/shared", "{tmp}/mine"),
])
def test_the_commands_store_is_store_then_the_variable_then_out_store(argv, env, expected, tmp_path, monkeypatch, capsys):
    from gimbal_lab import cli
    from gimbal_lab.studies import paper

    class Stop(Exception):
        pass

    def run_study(params, out, *, store=None, **kwargs):
        raise Stop(store.root)

    monkeypatch.setattr(paper, "run_study", run_study)
    if env is not None:
        monkeypatch.setenv(STORE_ENV, env.format(tmp=tmp_path))
    with pytest.raises(Stop) as caught:
        cli.main(["--debug", "run", "paper", "--quiet", *[a.format(tmp=tmp_path) for a in argv]])
    assert caught.value.args == (Path(expected.format(tmp=tmp_path)),)
    assert f"finished runs are kept in {expected.format(tmp=tmp_path)}" in capsys.readouterr().out


def test_an_empty_store_option_is_refused(tmp_path, capsys):
    from gimbal_lab import cli

    with pytest.raises(SystemExit):
        cli.main(["run", "paper", "--out", str(tmp_path), "--store", " "])
    assert "--store must name a folder, got an empty string" in capsys.readouterr().err
