"""Where the results store is when none is given (gimbal_lab.runner.default_store_root, the CLI's
--store): one store whatever the output folder; and how many local workers a sweep starts when it
names none (default_jobs)."""

import os
import sys
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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the XDG rule is Linux's")
def test_outside_the_checkout_the_store_is_in_the_users_cache_folder(tmp_path, monkeypatch):
    """Oracle: the XDG base directory rule, $XDG_CACHE_HOME (default ~/.cache) / the application."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert checkout_root() is None
    assert default_store_root() == tmp_path / "cache" / "gimbal-lab" / "store"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_store_root() == Path.home() / ".cache" / "gimbal-lab" / "store"


def test_the_variable_overrides_the_default(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(STORE_ENV, str(tmp_path / "elsewhere"))
    assert default_store_root() == tmp_path / "elsewhere"
    monkeypatch.setenv(STORE_ENV, "relative/store")  # taken from the current folder, made absolute
    assert default_store_root() == tmp_path / "relative" / "store"
    monkeypatch.setenv(STORE_ENV, "~/s")
    assert default_store_root() == Path.home() / "s"
    monkeypatch.setenv(STORE_ENV, "  ")  # blank: as if unset
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    if sys.platform.startswith("linux"):
        assert default_store_root() == tmp_path / "cache" / "gimbal-lab" / "store"


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


@pytest.mark.parametrize("argv, env, where, expected", [
    (["--out", "{tmp}/out"], None, "{tmp}", "{tmp}/cache/gimbal-lab/store"),
    (["--out", "{tmp}/out"], None, str(ROOT / "notebooks"), str(ROOT / "results" / "store")),
    (["--out", "{tmp}/out"], "{tmp}/shared", "{tmp}", "{tmp}/shared"),
    (["--out", "{tmp}/out", "--store", "{tmp}/mine"], "{tmp}/shared", "{tmp}", "{tmp}/mine"),
], ids=["outside-the-checkout", "inside-the-checkout", "variable", "store-option"])
def test_the_commands_store_is_store_then_the_variable_then_the_default_never_out(argv, env, where, expected, tmp_path,
                                                                                 monkeypatch, capsys):
    from gimbal_lab import cli
    from gimbal_lab.studies import paper

    if where.startswith(str(ROOT)) and not EDITABLE:
        pytest.skip("gimbal_lab is not imported from this checkout")
    if not sys.platform.startswith("linux"):
        pytest.skip("the expected cache folder follows the XDG rule")

    class Stop(Exception):
        pass

    def run_study(params, out, *, store=None, **kwargs):
        raise Stop(store.root)

    monkeypatch.setattr(paper, "run_study", run_study)
    monkeypatch.setattr(runner.ResultsStore, "_open", lambda self: None)  # nothing made in the checkout's store
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.chdir(where.format(tmp=tmp_path))
    if env is not None:
        monkeypatch.setenv(STORE_ENV, env.format(tmp=tmp_path))
    with pytest.raises(Stop) as caught:
        cli.main(["--debug", "run", "paper", "--quiet", *[a.format(tmp=tmp_path) for a in argv]])
    assert caught.value.args == (Path(expected.format(tmp=tmp_path)),)
    assert f"the store is {expected.format(tmp=tmp_path)}" in capsys.readouterr().out


TINY_SCENARIO = ('description = "two cells"\n[run]\nreplicates = 2\n[camera]\nfps = 10.0\n[target]\nperiod_s = 1.0\n'
                 '[sweep]\npointing = ["stabilised", "paper"]\n')


def test_a_second_out_folder_computes_no_run(tmp_path, monkeypatch, capsys):
    """`gimbal-lab run FILE --out A`, then `--out B`: outside a checkout, with no store named, both
    use the user's cache folder; the second computes no run, says so in its first line, and writes
    the same tables."""
    from gimbal_lab import cli

    computed, real = [], runner._run_one

    def run_one(config, *args, **kwargs):
        computed.append(config)
        return real(config, *args, **kwargs)

    monkeypatch.setattr(runner, "_run_one", run_one)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (tmp_path / "rig.toml").write_text(TINY_SCENARIO)
    lines = {}
    for out in ("A", "B"):
        status = cli.main(["run", "rig.toml", "--out", out, "--jobs", "1", "--quiet", "--no-clips"])
        assert status == 0
        lines[out] = capsys.readouterr().out.splitlines()
    assert len(computed) == 4  # all in the first
    store = default_store_root()
    assert len(list((store / "runs").glob("*.parquet"))) == 4 and not (tmp_path / "A" / "store").exists()
    assert lines["A"][0].endswith(f"0 stored, 4 to compute on 1 local processes; the store is {store}")
    assert lines["B"][0].endswith(f"4 stored, 0 to compute on 1 local processes; the store is {store}")
    for name in ("summary.csv", "verdicts.csv", "claims.md"):
        assert (tmp_path / "A" / "rig" / name).read_bytes() == (tmp_path / "B" / "rig" / name).read_bytes()


def test_an_empty_store_option_is_refused(tmp_path, capsys):
    from gimbal_lab import cli

    with pytest.raises(SystemExit):
        cli.main(["run", "paper", "--out", str(tmp_path), "--store", " "])
    assert "--store must name a folder, got an empty string" in capsys.readouterr().err
