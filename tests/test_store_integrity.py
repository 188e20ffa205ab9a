"""The results store's last gaps: every served sidecar field under a digest (keyed with
GIMBAL_LAB_STORE_KEY for shared stores), claim files that are not a gimbal-lab run's taken over at
once with a warning, and temporary names the lab checks are its own."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest
from pandas.testing import assert_frame_equal

from gimbal_lab import runner
from gimbal_lab.runner import ResultsStore, run
from gimbal_lab.simulation import TrackingConfig


def cfg(seed: int) -> TrackingConfig:
    """A cheap run: 160 x 120 px, 0.1 revolution (6 frames)."""
    return TrackingConfig().with_(revolutions=0.1, camera__width=160, camera__height=120, seed=seed)


@pytest.fixture(scope="module")
def computed():
    """Two runs computed once in this process (no store), saved into each test's own store."""
    return run([cfg(31), cfg(32)], jobs=1, progress=False)


def _stored(tmp_path, results) -> ResultsStore:
    store = ResultsStore(tmp_path / "store")
    for result in results:
        store.save(result)
    return store


def _canonical(fields: dict) -> bytes:
    """The sidecar's fields as the README states they are digested: JSON, keys sorted, no spaces."""
    return json.dumps(fields, sort_keys=True, separators=(",", ":")).encode()


# ------------------------------------------------------------------------------------------------
# the whole sidecar under a digest
# ------------------------------------------------------------------------------------------------
def test_the_sidecar_digest_is_sha256_of_every_other_field(tmp_path, computed, monkeypatch):
    monkeypatch.delenv(runner.STORE_KEY_ENV, raising=False)
    store = _stored(tmp_path, computed[:1])
    meta = json.loads(store.paths(computed[0].config)[1].read_text())
    seal = meta.pop("sidecar_digest")
    assert seal == {"sha256": hashlib.sha256(_canonical(meta)).hexdigest()}
    assert {"timing", "config", "table_sha256", "frames", "seed", "source_hash"} <= set(meta)


@pytest.mark.parametrize("edit", ["timing", "frames", "label", "package_version", "digest removed"])
def test_a_valid_json_edit_of_any_sidecar_field_is_never_served(tmp_path, computed, monkeypatch, edit):
    """Fields outside the table's digest (``timing`` is read by the lens sweep) edited into other
    valid JSON: the sidecar's own digest no longer fits, the entry is moved aside and named."""
    monkeypatch.delenv(runner.STORE_KEY_ENV, raising=False)
    store = _stored(tmp_path, computed[:1])
    sidecar = store.paths(computed[0].config)[1]
    meta = json.loads(sidecar.read_text())
    if edit == "timing":
        meta["timing"] = {k: (v * 2 if isinstance(v, float) else v) for k, v in meta["timing"].items()}
        assert meta["timing"] != json.loads(sidecar.read_text())["timing"]
    elif edit == "frames":
        meta["frames"] += 0  # unchanged value, but the file is rewritten: must still be served
    elif edit == "digest removed":
        del meta["sidecar_digest"]
    else:
        meta[edit] = "edited"
    sidecar.write_text(json.dumps(meta, indent=2))
    if edit == "frames":
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert store.load(computed[0].config).timing == computed[0].timing
        return
    with pytest.warns(RuntimeWarning, match=str(sidecar) + ".*(digest|does not match)") as caught:
        assert store.load(computed[0].config) is None
    assert len(caught) == 1 and "the run is recomputed" in str(caught[0].message)


def test_random_flips_of_the_sidecar_are_never_served(tmp_path, computed, monkeypatch):
    """The campaign's sidecar family: 300 random single-bit flips and byte overwrites of a stored
    sidecar (seeded). Each is refused with a warning naming the sidecar, or served identical to
    the clean entry (a flip in a JSON space or key order changes no field): 0 served damaged."""
    monkeypatch.delenv(runner.STORE_KEY_ENV, raising=False)
    store = _stored(tmp_path, computed[:1])
    clean = computed[0]
    table, sidecar = store.paths(clean.config)
    original, original_table = sidecar.read_bytes(), table.read_bytes()
    rng = np.random.default_rng(42)
    refused = served_clean = 0
    for i in range(300):
        data = bytearray(original)
        at = int(rng.integers(len(data)))
        if i % 2:
            data[at] ^= 1 << int(rng.integers(8))
        else:
            data[at] = (data[at] + int(rng.integers(1, 256))) % 256
        sidecar.write_bytes(bytes(data))
        table.write_bytes(original_table)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            loaded = store.load(clean.config)
        if loaded is None:
            assert any(str(sidecar) in str(w.message) for w in caught), (i, at)
            refused += 1
        else:  # served: every field it serves must be the clean one
            assert loaded.timing == clean.timing and loaded.config == clean.config, (i, at)
            assert_frame_equal(loaded.frames, clean.frames, check_exact=True)
            served_clean += 1
    print(f"\n[sidecar flips] 300: {refused} refused, {served_clean} served unchanged, 0 served damaged")
    assert refused + served_clean == 300 and refused >= 270


# ------------------------------------------------------------------------------------------------
# a keyed digest for shared stores
# ------------------------------------------------------------------------------------------------
def _tamper(store: ResultsStore, victim, donor, key: bytes | None) -> None:
    """Put ``donor``'s frames in ``victim``'s entry with a sidecar that agrees: table digest, row
    count and the sidecar's digest, sealed with ``key`` (None: plain SHA-256), as someone who can
    write the store but does not know the store's key would."""
    table, sidecar = store.paths(victim.config)
    data = store.paths(donor.config)[0].read_bytes()
    table.write_bytes(data)
    meta = json.loads(sidecar.read_text())
    meta.pop("sidecar_digest")
    meta["table_sha256"] = hashlib.sha256(data).hexdigest()
    body = _canonical(meta)
    meta["sidecar_digest"] = ({"sha256": hashlib.sha256(body).hexdigest()} if key is None
                              else {"hmac_sha256": hmac.new(key, body, hashlib.sha256).hexdigest()})
    sidecar.write_text(json.dumps(meta))


def test_an_unkeyed_store_serves_a_consistent_rewrite_the_documented_limit(tmp_path, computed, monkeypatch):
    """Without a key, a rewrite of table and sidecar together is served: the limit the README states."""
    monkeypatch.delenv(runner.STORE_KEY_ENV, raising=False)
    a, b = computed
    b_same_clock = b.frames.assign(frame=a.frames["frame"], t_s=a.frames["t_s"])  # fits a's config
    donor = runner.TrackingResult(config=b.config, frames=b_same_clock, timing=b.timing)
    store = _stored(tmp_path, [a, donor])
    _tamper(store, a, donor, None)
    loaded = store.load(a.config)
    assert loaded is not None and not loaded.frames.equals(a.frames)


def test_a_keyed_store_serves_only_entries_sealed_with_its_key(tmp_path, computed, monkeypatch):
    key = "a secret shared by the store's users"
    monkeypatch.setenv(runner.STORE_KEY_ENV, key)
    a, b = computed
    store = _stored(tmp_path, [a, b])
    sidecar = store.paths(a.config)[1]
    meta = json.loads(sidecar.read_text())
    seal = meta.pop("sidecar_digest")
    assert seal == {"hmac_sha256": hmac.new(key.encode(), _canonical(meta), hashlib.sha256).hexdigest()}
    assert_frame_equal(store.load(a.config).frames, a.frames, check_exact=True)  # its own key: served

    cases = {  # name: (how the entry is rewritten, the key set when it is read, the warning's words)
        "rewritten without the key": (lambda: _tamper(store, a, b, None), key, "is not sealed with"),
        "rewritten under a guessed key": (lambda: _tamper(store, a, b, b"guess"), key, "does not match its keyed"),
        "read without the key": (lambda: None, None, "is sealed with a key"),
        "read under another key": (lambda: None, "another key", "does not match its keyed"),
    }
    for name, (rewrite, read_key, words) in cases.items():
        monkeypatch.setenv(runner.STORE_KEY_ENV, key)
        store.save(a)
        rewrite()
        if read_key is None:
            monkeypatch.delenv(runner.STORE_KEY_ENV)
        else:
            monkeypatch.setenv(runner.STORE_KEY_ENV, read_key)
        with pytest.warns(RuntimeWarning, match=str(sidecar) + f" {words}"):
            assert store.load(a.config) is None, name


# ------------------------------------------------------------------------------------------------
# claim files that are not a gimbal-lab run's
# ------------------------------------------------------------------------------------------------
def _record(**changes) -> dict:
    pid = os.getpid()
    return {"host": runner._HOST, "boot": runner._BOOT_ID, "pid": pid, "start": runner._start_ticks(pid),
            "exe": runner._executable(pid), "token": "0" * 16, **changes}


@pytest.mark.parametrize("content, why", [
    (b"", "not JSON"),
    (b"\x00\xffgarbage", "not JSON"),
    (b"[1, 2]", "holds list"),
    (json.dumps({"pid": 1}).encode(), "no valid 'host'"),
    (json.dumps(_record(pid="1")).encode(), "no valid 'pid'"),
    (json.dumps(_record(pid=0)).encode(), "names no process"),
    (json.dumps(_record(start="yesterday")).encode(), "no valid 'start'"),
])
def test_a_claim_file_that_is_not_the_labs_is_taken_over_at_once_with_a_warning(tmp_path, content, why):
    c = cfg(33)
    store = ResultsStore(tmp_path / "store")
    claim = store.runs / f"{store.key(c)}.claim"
    claim.write_bytes(content)
    with pytest.warns(RuntimeWarning, match=f"{claim} is not a claim gimbal-lab wrote \\(.*{why}.*\\); taken over"):
        assert store.claim(c)
    assert json.loads(claim.read_text())["pid"] == os.getpid()
    store.release(c)


LOCKER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
if sys.argv[2] == "hold":
    fcntl.flock(fd, fcntl.LOCK_EX)
print("ready", flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("other", ["sleep", "python holding no lock", "python whose lock is gone", "pid 1"])
def test_a_claim_naming_a_live_process_that_is_not_a_gimbal_lab_run_is_taken_over(tmp_path, other):
    """Alive, on this machine, its start time right, but not holding the store lock its claim
    names: whatever the process (even a Python one, or one whose executable cannot be read), the
    claim is taken over at once."""
    c = cfg(34)
    store = ResultsStore(tmp_path / "store")
    claim = store.runs / f"{store.key(c)}.claim"
    lock = ".owner~not-held.lock"
    proc = None
    if other == "sleep":
        proc = subprocess.Popen(["sleep", "60"])
        deadline = time.monotonic() + 5
        while runner._executable(proc.pid) in (None, runner._executable(os.getpid())):  # until exec'd
            assert time.monotonic() < deadline
            time.sleep(0.01)
    elif other != "pid 1":
        proc = subprocess.Popen([sys.executable, "-c", LOCKER, str(store.runs / lock), "no"], stdout=subprocess.PIPE,
                                text=True)
        assert proc.stdout.readline() == "ready\n"
        if other == "python whose lock is gone":
            (store.runs / lock).unlink()
    pid = 1 if proc is None else proc.pid
    try:
        claim.write_text(json.dumps(_record(pid=pid, start=runner._start_ticks(pid), lock=lock)))
        with pytest.warns(RuntimeWarning, match=f"{claim} names process {pid} \\(.*\\), which is not a gimbal-lab run "
                                                "\\(it holds no store lock\\); taken over"):
            assert store.claim(c)
    finally:
        if proc is not None:
            proc.kill()
            proc.wait()
    store.release(c)


def test_a_claim_whose_owner_holds_its_lock_is_respected(tmp_path):
    c = cfg(34)
    store = ResultsStore(tmp_path / "store")
    claim = store.runs / f"{store.key(c)}.claim"
    lock = ".owner~held.lock"
    proc = subprocess.Popen([sys.executable, "-c", LOCKER, str(store.runs / lock), "hold"], stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline() == "ready\n"
        claim.write_text(json.dumps(_record(pid=proc.pid, start=runner._start_ticks(proc.pid), lock=lock)))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert not store.claim(c)
    finally:
        proc.kill()
        proc.wait()
    assert store.claim(c)  # once its owner is gone
    store.release(c)


def test_lock_files_nobody_holds_are_removed_when_a_store_is_opened(tmp_path):
    from gimbal_lab import outputs

    store = ResultsStore(tmp_path / "store")
    core = f"{runner._HOST}~123~0a1b"
    ours = store.runs / f".owner~{core}~{outputs._check_tag(core)}.lock"  # a killed owner's, unlocked
    lookalike = store.runs / f".owner~{core}~ffffff.lock"
    for path in (ours, lookalike):
        path.write_text("")
    assert store.claim(cfg(37))  # this object's own lock, held
    ResultsStore(store.root)
    assert not ours.exists() and lookalike.exists()
    assert len(list(store.runs.glob(".owner~*.lock"))) == 2  # the lookalike and the held one
    store.release_all()


def test_a_sweep_meeting_a_garbage_claim_runs_at_once(tmp_path, monkeypatch):
    """The campaign's claim family: a garbage claim used to hold a sweep for CLAIM_STALE_S (300 s)."""
    c = cfg(35)
    store = ResultsStore(tmp_path / "store")
    (store.runs / f"{store.key(c)}.claim").write_text("{ garbage")
    t0 = time.monotonic()
    with pytest.warns(RuntimeWarning, match="is not a claim gimbal-lab wrote"):
        [result] = run([c], store=store, jobs=1, progress=False)
    assert time.monotonic() - t0 < 60 and result.config == c
    assert not list(store.runs.glob("*.claim"))


def test_garbage_claims_are_cleared_when_a_store_is_opened_and_other_files_are_left(tmp_path):
    store = ResultsStore(tmp_path / "store")
    garbage = store.runs / f"{'a' * 24}.claim"
    garbage.write_text("not a claim")
    mine = store.runs / "notes.claim"  # not named like a run's claim: never the store's to judge
    mine.write_text("not a claim either")
    with pytest.warns(RuntimeWarning, match=f"{garbage} is not a claim gimbal-lab wrote .*; removed"):
        ResultsStore(store.root)
    assert not garbage.exists() and mine.exists()


def test_a_claim_is_never_seen_half_written(tmp_path, monkeypatch):
    """A claim is linked into place whole: the O_EXCL path (where links fail) is the fallback."""
    c = cfg(36)
    store = ResultsStore(tmp_path / "store")
    seen = []
    real_link = os.link

    def link(src, dst, **kwargs):
        seen.append(json.loads(open(src, "rb").read()))  # the file that appears is already whole
        return real_link(src, dst, **kwargs)

    monkeypatch.setattr(runner.os, "link", link)
    assert store.claim(c) and seen and seen[0]["pid"] == os.getpid()
    store.release(c)

    def no_links(src, dst, **kwargs):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(runner.os, "link", no_links)
    assert store.claim(c) and json.loads((store.runs / f"{store.key(c)}.claim").read_text())["pid"] == os.getpid()
    assert not [p for p in store.runs.iterdir() if p.name.endswith(".tmp")]
    store.release(c)
