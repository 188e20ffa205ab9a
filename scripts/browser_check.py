"""Check in a real browser that the run explorer of notebook 07 works.

The explorer is the notebook cell whose source starts with ``plotting.study.run_explorer(``: an
ipywidgets ``interactive`` (two dropdowns, cell and replicate, and a frame slider) that redraws a
matplotlib figure, shown as a PNG in the widget's output area, on every change. Static runs of the
notebook (nbmake) only see its first picture; this script checks the live round trip
browser -> kernel -> browser:

1. start ``jupyter lab`` on a free local port, serving the notebook's folder (notebooks/ by
   default: the notebook reads and writes its runs in notebooks/results/store relative to it);
2. open the notebook in headless Chromium (Selenium + chromedriver) and run every cell through
   the menu "Run > Run All Cells", printing progress until the kernel is idle (if the results
   store is empty, the notebook first computes its ~160 closed-loop runs: minutes, not seconds);
3. read the explorer's image, press End on the frame slider and wait for a new image, then pick
   another replicate and wait for a new image again; the three PNGs are decoded and must differ;
4. print a PASS/FAIL summary with timings; the server and the browser are always shut down.

The notebook file is not saved (autosave is switched off in a throw-away JupyterLab settings
folder) and is checked to be unchanged at the end.

Prerequisites (checked first; exit status 2 names what is missing)::

    apt-get install -y chromium chromium-driver     # Debian; the two versions must match
    pip install -e '.[browser]'                     # jupyterlab, ipywidgets, selenium

Run from the repository root, in the project's environment::

    PYOPENGL_PLATFORM=egl python scripts/browser_check.py [--notebook PATH] [--timeout S] [--out DIR]
    python scripts/browser_check.py --video results/paper/clips/sphere.mp4    # a clip plays in Chromium

``PYOPENGL_PLATFORM`` defaults to ``egl`` for the kernel when unset (headless rendering).
Outputs in ``--out`` (default /tmp/browser_check): explorer_0_initial.png,
explorer_1_frame.png, explorer_2_replicate.png (the images as the browser received them),
page.png (a screenshot of the browser window with the explorer in view), summary.txt and the
logs jupyter.log and chromedriver.log. Ctrl-C stops the check and cleans up.

Exit status: 0 PASS, 1 FAIL (or interrupted), 2 missing prerequisites.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import importlib.util
import io
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEFAULT_NOTEBOOK = REPO / "notebooks" / "07_active-vs-passive-sphere.ipynb"
DEFAULT_OUT = Path("/tmp/browser_check")
EXPLORER_PREFIX = "plotting.study.run_explorer("
WINDOW = (1600, 1200)
UPDATE_TIMEOUT_S = 120  # one widget change: two renders and a figure, about a second when warm
MIN_CHANGED_FRACTION = 0.001  # share of pixels that must differ between two explorer images

EXIT_PASS, EXIT_FAIL, EXIT_PREREQUISITES = 0, 1, 2


class CheckFailed(Exception):
    """A step of the check did not do what it should; the message says what was seen."""


# --------------------------------------------------------------------------- prerequisites


def find_browser() -> tuple[str | None, str | None]:
    """Paths of the Chromium binary and of chromedriver, or None where not found."""
    chromium = next((p for p in map(shutil.which, ("chromium", "chromium-browser")) if p), None)
    return chromium, shutil.which("chromedriver")


def major_version(binary: str) -> int | None:
    """The major version printed by ``binary --version`` (Chromium and chromedriver alike)."""
    try:
        out = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    match = re.search(r"(\d+)\.\d+\.\d+", out)
    return int(match.group(1)) if match else None


def check_prerequisites(notebook: Path | None) -> list[str]:
    """Everything missing to run the check, each with how to get it (empty: all present). Without
    ``notebook`` (the clip check), only the browser, chromedriver, selenium and PyAV."""
    problems = []
    chromium, chromedriver = find_browser()
    if chromium is None:
        problems.append("Chromium is not installed: apt-get install -y chromium")
    if chromedriver is None:
        problems.append("chromedriver is not installed: apt-get install -y chromium-driver")
    if chromium and chromedriver:
        browser_major, driver_major = major_version(chromium), major_version(chromedriver)
        if browser_major is None or driver_major is None:
            problems.append(f"cannot read the versions of {chromium} and {chromedriver} (--version)")
        elif browser_major != driver_major:
            problems.append(f"Chromium {browser_major} and chromedriver {driver_major} differ: "
                            "apt-get install -y chromium chromium-driver (same release)")
    if importlib.util.find_spec("selenium") is None:
        problems.append(f"selenium is not importable by {sys.executable}: pip install selenium")
    if notebook is None:
        if importlib.util.find_spec("av") is None:
            problems.append(f"PyAV is not importable by {sys.executable}: pip install -e . (from the repository root)")
        return problems
    for module in ("jupyterlab", "ipywidgets", "ipykernel"):
        if importlib.util.find_spec(module) is None:
            problems.append(f"{module} is not importable by {sys.executable}: pip install -e '.[notebooks]' "
                            "(from the repository root)")
    if problems and sys.prefix == sys.base_prefix:
        problems.append(f"{sys.executable} is not a virtual environment: run the script with the project's environment"
                        " (. .venv/bin/activate)")
    if importlib.util.find_spec("PIL") is None or importlib.util.find_spec("numpy") is None:
        problems.append("Pillow and numpy are needed to compare the images: pip install pillow numpy")
    if not notebook.is_file():
        problems.append(f"no notebook at {notebook}")
    elif explorer_cell_index(notebook) is None:
        problems.append(f"{notebook.name} has no code cell starting with {EXPLORER_PREFIX!r}")
    return problems


def explorer_cell_index(notebook: Path) -> int | None:
    """Index among the code cells of the explorer cell, read from the notebook file."""
    try:
        cells = json.loads(notebook.read_text(encoding="utf-8"))["cells"]
    except (OSError, ValueError, KeyError):
        return None
    code = [c for c in cells if c.get("cell_type") == "code"]
    for i, c in enumerate(code):
        source = "".join(c.get("source", ""))
        if source.lstrip().startswith(EXPLORER_PREFIX):
            return i
    return None


# --------------------------------------------------------------------------- the server


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_lab_settings(settings_dir: Path) -> None:
    """JupyterLab user settings for an unattended run: never save the notebook, keep every cell
    in the page (no windowing, so every prompt and output can be read) and no news pop-up."""
    settings = {
        "docmanager-extension/plugin": {"autosave": False},
        "notebook-extension/tracker": {"windowingMode": "none"},
        "apputils-extension/notification": {"fetchNews": "false", "checkForUpdates": False},
    }
    for name, values in settings.items():
        path = settings_dir / "@jupyterlab" / f"{name}.jupyterlab-settings"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(values), encoding="utf-8")


class LabServer:
    """``jupyter lab`` serving one folder on 127.0.0.1 with a fresh token, its state in a
    scratch folder (settings, workspaces, checkpoints, runtime files) and its log in a file."""

    def __init__(self, root: Path, scratch: Path, log_path: Path):
        self.root = root
        self.scratch = scratch
        self.log_path = log_path
        self.port = free_port()
        self.token = secrets.token_hex(16)
        self.process: subprocess.Popen | None = None
        self._log = None

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        write_lab_settings(self.scratch / "settings")
        env = dict(os.environ)
        env.setdefault("PYOPENGL_PLATFORM", "egl")
        env["PATH"] = os.pathsep.join((str(Path(sys.executable).parent), env.get("PATH", "")))
        env["JUPYTER_RUNTIME_DIR"] = str(self.scratch / "runtime")
        env["JUPYTER_CONFIG_DIR"] = str(self.scratch / "config")
        command = [
            sys.executable, "-m", "jupyterlab",
            "--no-browser", "--ip", "127.0.0.1", "--port", str(self.port), "--allow-root",
            "--ServerApp.port_retries=0",
            f"--ServerApp.token={self.token}",
            f"--ServerApp.root_dir={self.root}",
            f"--LabApp.user_settings_dir={self.scratch / 'settings'}",
            f"--LabApp.workspaces_dir={self.scratch / 'workspaces'}",
            f"--FileCheckpoints.checkpoint_dir={self.scratch / 'checkpoints'}",
            # no request for the Jupyter news feed; the pop-up asking about it is answered by the
            # fetchNews setting of write_lab_settings (this flag alone still shows it)
            "--LabApp.news_url=None",
        ]
        self._log = open(self.log_path, "w", encoding="utf-8")
        # Its own session: Ctrl-C in the terminal reaches only this script, which then stops it.
        self.process = subprocess.Popen(command, cwd=self.root, env=env, stdin=subprocess.DEVNULL,
                                        stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)

    def api(self, path: str, method: str = "GET", timeout: float = 10):
        """JSON answer of the server's REST API at ``path``."""
        request = urllib.request.Request(f"{self.base_url}{path}", method=method,
                                         headers={"Authorization": f"token {self.token}"})
        with urllib.request.urlopen(request, timeout=timeout) as answer:
            body = answer.read()
        return json.loads(body) if body else None

    def wait_ready(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise CheckFailed(f"jupyter lab exited with status {self.process.returncode}; "
                                  f"see {self.log_path}:\n{tail(self.log_path)}")
            try:
                self.api("/api/status", timeout=2)
                return
            except (urllib.error.URLError, OSError, ValueError):
                time.sleep(0.5)
        raise CheckFailed(f"jupyter lab did not answer within {timeout:.0f} s; see {self.log_path}")

    def kernel_state(self, notebook_name: str) -> str | None:
        """Execution state of the kernel of the notebook's session (None: no session yet)."""
        for session in self.api("/api/sessions"):
            if session.get("path", "").split("/")[-1] == notebook_name and session.get("kernel"):
                return session["kernel"].get("execution_state")
        return None

    def notebook_url(self, notebook_name: str) -> str:
        # `reset` starts from an empty workspace: only this notebook open.
        return (f"{self.base_url}/lab/tree/{urllib.parse.quote(notebook_name)}"
                f"?reset&token={self.token}")

    def stop(self) -> None:
        """Ask the server to shut down (it stops its kernels); terminate its process group if it
        does not exit in time."""
        if self.process is None:
            return
        if self.process.poll() is None:
            try:
                self.api("/api/shutdown", method="POST", timeout=5)
            except (urllib.error.URLError, OSError, ValueError):
                pass
            for sig, wait_s in ((None, 15), (signal.SIGTERM, 10), (signal.SIGKILL, 5)):
                if sig is not None:
                    try:
                        os.killpg(self.process.pid, sig)
                    except ProcessLookupError:
                        break
                try:
                    self.process.wait(timeout=wait_s)
                    break
                except subprocess.TimeoutExpired:
                    continue
        if self._log is not None:
            self._log.close()
        self.process = None


def tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(encoding="utf-8", errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


# --------------------------------------------------------------------------- the browser

# State of the open notebook: the input prompt of every code cell ("[3]:", "[*]:", "[ ]:") and,
# for the first cell still waiting or running, the first line of its source and its output text.
NOTEBOOK_STATE_JS = """
const panel = document.querySelector('.jp-NotebookPanel:not(.lm-mod-hidden)');
if (!panel) return null;
const cells = [...panel.querySelectorAll('.jp-Notebook .jp-CodeCell')];
const prompts = cells.map(c => {
  const p = c.querySelector('.jp-InputArea-prompt');
  return p ? p.textContent.trim() : '';
});
const i = prompts.findIndex(p => p.includes('*'));
let running = null;
if (i >= 0) {
  const src = cells[i].querySelector('.cm-content');
  const out = cells[i].querySelector('.jp-OutputArea');
  running = {index: i, source: src ? src.innerText.split('\\n')[0] : '', output: out ? out.innerText : ''};
}
return {prompts: prompts, running: running};
"""

FIND_EXPLORER_JS = """
const panel = document.querySelector('.jp-NotebookPanel:not(.lm-mod-hidden)');
if (!panel) return null;
for (const cell of panel.querySelectorAll('.jp-Notebook .jp-CodeCell')) {
  const src = cell.querySelector('.jp-InputArea-editor .cm-content');
  if (src && src.textContent.trimStart().startsWith(arguments[0])) return cell;
}
return null;
"""

# The explorer's output area: how many images it shows, a digest of the first one's src (cheap
# to poll; the src itself is a few hundred kB), and the text of its other outputs.
EXPLORER_OUTPUT_JS = """
const out = arguments[0].querySelector('.widget-interact .widget-output');
if (!out) return null;
const imgs = [...out.querySelectorAll('img')];
let digest = null;
if (imgs.length) {
  const s = imgs[0].getAttribute('src') || '';
  let h = 2166136261;
  for (let k = 0; k < s.length; k++) { h ^= s.charCodeAt(k); h = Math.imul(h, 16777619) >>> 0; }
  digest = s.length + ':' + h;
}
const texts = [...out.querySelectorAll('.jp-OutputArea-output')]
  .filter(e => !e.querySelector('img')).map(e => e.innerText.trim()).filter(t => t);
return {images: imgs.length, digest: digest, text: texts.join('\\n')};
"""


def start_browser(chromium: str, chromedriver: str, log_path: Path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                f"--window-size={WINDOW[0]},{WINDOW[1]}"):
        options.add_argument(arg)
    # chromedriver and Chromium in their own session too: a Ctrl-C must not kill them under the
    # script's feet; driver.quit() ends them.
    service = Service(executable_path=chromedriver, log_output=str(log_path),
                      popen_kw={"start_new_session": True})
    driver = webdriver.Chrome(service=service, options=options)
    # The window size includes the (invisible) browser frame; make the page itself WINDOW.
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                           {"width": WINDOW[0], "height": WINDOW[1], "deviceScaleFactor": 1, "mobile": False})
    return driver


def wait_until(condition, timeout: float, what: str, poll: float = 0.25):
    """Poll ``condition()`` until it returns something truthy; CheckFailed after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise CheckFailed(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(poll)


def accept_kernel_dialog(driver) -> None:
    """Accept a "Select Kernel" dialog if JupyterLab shows one (no matching kernel name)."""
    from selenium.webdriver.common.by import By

    for dialog in driver.find_elements(By.CSS_SELECTOR, ".jp-Dialog"):
        if "kernel" in dialog.text.lower():
            buttons = dialog.find_elements(By.CSS_SELECTOR, "button.jp-mod-accept")
            if buttons:
                buttons[0].click()


def open_notebook(driver, server: LabServer, notebook_name: str, timeout: float) -> None:
    """Load the notebook in JupyterLab and wait until its kernel is up and idle."""
    driver.get(server.notebook_url(notebook_name))

    def ready():
        accept_kernel_dialog(driver)
        state = driver.execute_script(NOTEBOOK_STATE_JS)
        return state and state["prompts"] and server.kernel_state(notebook_name) == "idle"

    wait_until(ready, timeout, f"{notebook_name} to open with an idle kernel", poll=0.5)


def run_all_cells(driver) -> None:
    """Menu "Run > Run All Cells", as a user would do it."""
    from selenium.webdriver.common.by import By

    menus = [m for m in driver.find_elements(By.CSS_SELECTOR, ".lm-MenuBar-item") if m.text.strip() == "Run"]
    if not menus:
        raise CheckFailed("JupyterLab shows no Run menu")
    menus[0].click()
    item = wait_until(lambda: driver.find_elements(By.CSS_SELECTOR, '.lm-Menu-item[data-command="runmenu:run-all"]'),
                      10, 'the menu item "Run All Cells"')
    item[0].click()


def executed(prompt: str) -> bool:
    return re.fullmatch(r"\[\d+\]:?", prompt) is not None


def wait_for_run(driver, server: LabServer, notebook_name: str, timeout: float, progress_every: float = 15):
    """Wait until every code cell has run; print which cell runs (and its latest output line)
    every ``progress_every`` seconds. CheckFailed if a cell did not run (an error stops Run All)."""
    start = time.monotonic()
    last_report = start
    idle_since = None
    started = False
    while True:
        state = driver.execute_script(NOTEBOOK_STATE_JS) or {"prompts": [], "running": None}
        prompts = state["prompts"]
        done = sum(map(executed, prompts))
        started = started or state["running"] is not None or (prompts and done == len(prompts))
        kernel = server.kernel_state(notebook_name)
        now = time.monotonic()
        # Done: the run has started, nothing is waiting, the kernel is idle, and all still true a
        # moment later (the kernel is briefly idle between two cells).
        if started and state["running"] is None and kernel == "idle":
            idle_since = idle_since or now
            if now - idle_since > 2:
                break
        else:
            idle_since = None
        if not started and now - start > 30:
            raise CheckFailed("no cell started within 30 s of Run All Cells")
        if now - start > timeout:
            raise CheckFailed(f"the notebook had not finished after {timeout:.0f} s "
                              f"({done}/{len(prompts)} code cells done); raise --timeout")
        if now - last_report >= progress_every:
            last_report = now
            line = f"  {now - start:5.0f} s  {done}/{len(prompts)} code cells done"
            if state["running"]:
                r = state["running"]
                line += f", running cell {r['index'] + 1}: {r['source'][:60]}"
                out = " ".join(r["output"].split())
                if out:
                    line += f"  | {out[-90:]}"
            print(line, flush=True)
        time.sleep(0.5)
    not_run = [i + 1 for i, p in enumerate(prompts) if not executed(p)]
    if not_run:
        raise CheckFailed(f"code cells {not_run} did not run (an earlier cell raised?); "
                          f"last output: {last_error_text(driver)}")
    return len(prompts)


def last_error_text(driver) -> str:
    """Text of the last stderr/error output in the notebook, for a failure message."""
    text = driver.execute_script("""
      const panel = document.querySelector('.jp-NotebookPanel:not(.lm-mod-hidden)');
      const outs = panel ? [...panel.querySelectorAll(
        '.jp-OutputArea-output[data-mime-type="application/vnd.jupyter.stderr"]')] : [];
      return outs.length ? outs[outs.length - 1].innerText : '';""")
    return " ".join(text.split())[-400:] or "(none shown)"


# --------------------------------------------------------------------------- the explorer


class Explorer:
    """The explorer widget of the open notebook, located by its cell's source."""

    def __init__(self, driver):
        self.driver = driver
        self.cell = driver.execute_script(FIND_EXPLORER_JS, EXPLORER_PREFIX)
        if self.cell is None:
            raise CheckFailed(f"no code cell starting with {EXPLORER_PREFIX!r} in the page")

    def output(self) -> dict:
        return self.driver.execute_script(EXPLORER_OUTPUT_JS, self.cell) or {"images": 0, "digest": None, "text": ""}

    def image_png(self) -> bytes:
        from selenium.webdriver.common.by import By

        src = self.cell.find_element(By.CSS_SELECTOR, ".widget-interact .widget-output img").get_attribute("src")
        prefix = "data:image/png;base64,"
        if not src.startswith(prefix):
            raise CheckFailed(f"the explorer's image is not an inline PNG: {src[:60]}...")
        return base64.b64decode(src[len(prefix):])

    def wait_for_image(self, timeout: float, previous: str | None = None) -> str:
        """Wait until the output shows an image whose src differs from digest ``previous``, then
        until it has stayed the same for a second (no second redraw on the way). Its digest."""
        def new_image():
            out = self.output()
            if out["digest"] and out["digest"] != previous:
                return out["digest"]
            if out["text"] and not out["images"]:
                raise CheckFailed(f"the explorer shows text instead of an image: ...{out['text'][-600:]}")
            return None

        digest = wait_until(new_image, timeout, "a new image in the explorer's output")
        stable_since = time.monotonic()
        while time.monotonic() - stable_since < 1.0:
            time.sleep(0.2)
            current = self.output()["digest"]
            if current != digest:
                digest, stable_since = current, time.monotonic()
        return digest

    def _find(self, css: str):
        from selenium.webdriver.common.by import By

        found = self.cell.find_elements(By.CSS_SELECTOR, css)
        if not found:
            raise CheckFailed(f"the explorer has no {css!r}")
        return found[0]

    def frame(self) -> str:
        return self._find(".widget-interact .widget-slider .widget-readout").text.strip()

    def press_on_slider(self, key) -> None:
        """Focus the frame slider's handle and press ``key`` (the value is sent on the key event,
        the slider having continuous_update=False)."""
        handle = self._find(".widget-interact .widget-slider .noUi-handle")
        self.driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", handle)
        handle.send_keys(key)

    def dropdown(self, label: str):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        for box in self.cell.find_elements(By.CSS_SELECTOR, ".widget-interact .widget-dropdown"):
            if box.find_element(By.CSS_SELECTOR, "label").text.strip() == label:
                return Select(box.find_element(By.CSS_SELECTOR, "select"))
        raise CheckFailed(f"the explorer has no dropdown {label!r}")

    def scroll_into_view(self) -> None:
        self.driver.execute_script("arguments[0].scrollIntoView({block: 'start'});", self.cell)


def compare_pngs(a: bytes, b: bytes) -> float:
    """Share of pixels that differ between two PNGs (1.0 if their sizes differ)."""
    import numpy as np
    from PIL import Image

    x = np.asarray(Image.open(io.BytesIO(a)).convert("RGB"))
    y = np.asarray(Image.open(io.BytesIO(b)).convert("RGB"))
    if x.shape != y.shape:
        return 1.0
    return float(np.any(x != y, axis=-1).mean())


def describe_png(data: bytes) -> str:
    from PIL import Image

    image = Image.open(io.BytesIO(data))
    return f"{image.width}x{image.height} px, {len(data) / 1024:.0f} kB"


# --------------------------------------------------------------------------- the check


class Report:
    """Timed steps and pass/fail checks, printed as they happen and summarised at the end."""

    def __init__(self):
        self.timings: list[tuple[str, float]] = []
        self.checks: list[tuple[str, bool, str]] = []
        self.failure: str | None = None

    def time(self, name: str, seconds: float) -> None:
        self.timings.append((name, seconds))
        print(f"  {name}: {seconds:.1f} s", flush=True)

    def check(self, name: str, ok: bool, detail: str = "") -> bool:
        self.checks.append((name, ok, detail))
        print(f"  [{'ok' if ok else 'FAILED'}] {name}" + (f" ({detail})" if detail else ""), flush=True)
        return ok

    @property
    def passed(self) -> bool:
        return self.failure is None and bool(self.checks) and all(ok for _, ok, _ in self.checks)

    def summary(self) -> str:
        lines = ["", "=" * 72, f"browser check: {'PASS' if self.passed else 'FAIL'}"]
        if self.failure:
            lines.append(f"  failure: {self.failure}")
        lines.append("  timings:")
        lines += [f"    {name:<40} {seconds:8.1f} s" for name, seconds in self.timings]
        lines.append("  checks:")
        lines += [f"    [{'ok' if ok else 'FAILED'}] {name}" + (f": {detail}" if detail else "")
                  for name, ok, detail in self.checks]
        lines.append("=" * 72)
        return "\n".join(lines)


def step(report: Report, name: str):
    """Context manager timing a step into ``report``."""
    class _Step:
        def __enter__(self):
            print(f"{name} ...", flush=True)
            self.start = time.monotonic()
            return self

        def __exit__(self, *exc):
            if exc[0] is None:
                report.time(name, time.monotonic() - self.start)
            return False

    return _Step()


def exercise_explorer(driver, server, notebook_name: str, out_dir: Path, report: Report) -> None:
    """The widget part: initial image, slider change, replicate change; saves the three PNGs."""
    from selenium.webdriver.common.keys import Keys

    def settle():
        wait_until(lambda: server.kernel_state(notebook_name) == "idle", UPDATE_TIMEOUT_S, "the kernel to be idle")

    with step(report, "explorer: first image"):
        explorer = Explorer(driver)
        explorer.scroll_into_view()
        digest = explorer.wait_for_image(UPDATE_TIMEOUT_S)
    images = [("initial", explorer.frame(), explorer.image_png())]
    (out_dir / "explorer_0_initial.png").write_bytes(images[0][2])
    print(f"  frame {images[0][1]}, image {describe_png(images[0][2])}")

    with step(report, "widget update: frame slider (End)"):
        explorer.press_on_slider(Keys.END)
        digest = explorer.wait_for_image(UPDATE_TIMEOUT_S, previous=digest)
    settle()
    images.append(("frame", explorer.frame(), explorer.image_png()))
    (out_dir / "explorer_1_frame.png").write_bytes(images[1][2])
    report.check("the frame slider moved", images[1][1] != images[0][1],
                 f"frame {images[0][1]} -> {images[1][1]}")

    replicate = explorer.dropdown("replicate")
    options = [o.text for o in replicate.options]
    before = replicate.first_selected_option.text
    if len(options) < 2:
        raise CheckFailed(f"the replicate dropdown offers only {options}")
    choice = (options.index(before) + 1) % len(options)
    with step(report, "widget update: replicate dropdown"):
        replicate.select_by_index(choice)
        digest = explorer.wait_for_image(UPDATE_TIMEOUT_S, previous=digest)
    settle()
    after = explorer.dropdown("replicate").first_selected_option.text
    images.append(("replicate", explorer.frame(), explorer.image_png()))
    (out_dir / "explorer_2_replicate.png").write_bytes(images[2][2])
    report.check("the replicate changed", after != before, f"replicate {before} -> {after}")

    for (name_a, _, a), (name_b, _, b) in zip(images, images[1:]):
        changed = compare_pngs(a, b)
        report.check(f"image {name_a} -> {name_b} differs", changed >= MIN_CHANGED_FRACTION,
                     f"{100 * changed:.1f} % of pixels changed")
    out = explorer.output()
    report.check("the explorer shows one image and no error text", out["images"] == 1 and not out["text"],
                 f"{out['images']} image(s)" + (f", text: {out['text'][:200]}" if out["text"] else ""))
    explorer.scroll_into_view()


def run_check(args, report: Report, scratch: Path) -> None:
    notebook: Path = args.notebook
    out_dir: Path = args.out
    chromium, chromedriver = find_browser()
    digest_before = hashlib.sha256(notebook.read_bytes()).hexdigest()
    store = notebook.parent / "results" / "store"
    if not store.is_dir() or not any(store.rglob("*.json")):
        print(f"note: no stored runs in {store}; the notebook computes them first (several minutes)")

    server = LabServer(notebook.parent, scratch, out_dir / "jupyter.log")
    driver = None
    try:
        with step(report, f"server start (jupyter lab on port {server.port})"):
            server.start()
            server.wait_ready(120)
        with step(report, "browser start"):
            driver = start_browser(chromium, chromedriver, out_dir / "chromedriver.log")
        try:
            with step(report, "notebook open (kernel idle)"):
                open_notebook(driver, server, notebook.name, 180)
            with step(report, "notebook run (Run All Cells)"):
                run_all_cells(driver)
                n_cells = wait_for_run(driver, server, notebook.name, args.timeout)
            report.check("every code cell ran", True, f"{n_cells} code cells")
            exercise_explorer(driver, server, notebook.name, out_dir, report)
        finally:
            try:
                driver.save_screenshot(str(out_dir / "page.png"))
            except Exception as error:  # the browser may be gone already
                print(f"  (no screenshot: {type(error).__name__})")
    finally:
        if driver is not None:
            try:
                driver.quit()
            except Exception as error:
                print(f"  (browser did not quit cleanly: {type(error).__name__})")
        server.stop()
        digest_after = hashlib.sha256(notebook.read_bytes()).hexdigest()
        report.check("the notebook file is unchanged", digest_after == digest_before)


VIDEO_STATE_JS = """
const v = document.getElementById('clip');
return {readyState: v.readyState, duration: v.duration, width: v.videoWidth, height: v.videoHeight,
        error: v.error ? v.error.code + ' ' + (v.error.message || '') : null};
"""


def check_video(args, report: Report, scratch: Path) -> None:
    """Open ``args.video`` in a ``<video>`` element of headless Chromium: it must load (readyState
    >= 2, HAVE_CURRENT_DATA: a frame can be shown), with the duration and size PyAV reads."""
    from gimbal_lab.video import probe_video

    clip: Path = args.video
    info = probe_video(clip)
    report.check("the clip is H.264 in 4:2:0", (info.codec, info.pixel_format) == ("h264", "yuv420p"),
                 f"{info.codec}, {info.pixel_format}, {info.width}x{info.height}, {info.frames} frames, "
                 f"{info.duration_s:.3f} s")
    page = scratch / "clip.html"
    page.write_text(f'<!doctype html><video id="clip" src="{clip.as_uri()}" muted preload="auto"></video>',
                    encoding="utf-8")
    chromium, chromedriver = find_browser()
    driver = None
    try:
        with step(report, "browser start"):
            driver = start_browser(chromium, chromedriver, args.out / "chromedriver.log")
        with step(report, "clip load"):
            driver.get(page.as_uri())
            state = wait_until(lambda: (lambda s: s if s["readyState"] >= 2 or s["error"] else None)(
                driver.execute_script(VIDEO_STATE_JS)), 60, "the video element to load the clip")
        frame_s = 1.0 / info.fps if info.fps else 0.05
        report.check("the browser plays the clip (readyState >= 2, no media error)",
                     state["readyState"] >= 2 and not state["error"],
                     f"readyState {state['readyState']}" + (f", error {state['error']}" if state["error"] else ""))
        duration = state["duration"] if isinstance(state["duration"], (int, float)) else float("nan")
        report.check("its duration is the file's (within one frame)", abs(duration - info.duration_s) <= frame_s,
                     f"browser {duration:.3f} s, file {info.duration_s:.3f} s")
        report.check("its size is the file's", (state["width"], state["height"]) == (info.width, info.height),
                     f"browser {state['width']}x{state['height']}")
        driver.save_screenshot(str(args.out / "clip.png"))
    finally:
        if driver is not None:
            driver.quit()


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--notebook", type=Path, default=DEFAULT_NOTEBOOK,
                        help="notebook holding the explorer; the server serves its folder (default: %(default)s)")
    parser.add_argument("--timeout", type=float, default=900,
                        help="seconds allowed for running all cells (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="folder for the PNGs, the screenshot and the logs (default: %(default)s)")
    parser.add_argument("--video", type=Path, metavar="CLIP.mp4",
                        help="instead of the notebook: check that Chromium plays this clip in a <video> element "
                             "(e.g. results/paper/clips/sphere.mp4)")
    args = parser.parse_args(argv)
    args.notebook = args.notebook.resolve()
    if args.video is not None:
        args.video = args.video.resolve()
        if not args.video.is_file():
            parser.error(f"--video {args.video}: no such file")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    problems = check_prerequisites(None if args.video else args.notebook)
    if problems:
        print("browser check: missing prerequisites", file=sys.stderr)
        for problem in problems:
            print(f"  - {problem}", file=sys.stderr)
        return EXIT_PREREQUISITES

    def terminate(signum, frame):
        raise KeyboardInterrupt

    for signum in (signal.SIGINT, signal.SIGTERM):  # also when started with SIGINT ignored (`&`)
        signal.signal(signum, terminate)
    args.out.mkdir(parents=True, exist_ok=True)
    report = Report()
    scratch = Path(tempfile.mkdtemp(prefix="browser_check-"))
    what = f"that Chromium plays {args.video}" if args.video else f"the explorer of {args.notebook}"
    print(f"checking {what} (outputs in {args.out})", flush=True)
    try:
        if args.video:
            check_video(args, report, scratch)
        else:
            run_check(args, report, scratch)
    except CheckFailed as error:
        report.failure = str(error)
    except KeyboardInterrupt:
        report.failure = "interrupted"
    except Exception as error:  # a browser or server error: a failure, with its type
        message = getattr(error, "msg", None) or str(error)  # WebDriver errors: without the stack
        report.failure = f"{type(error).__name__}: {message.strip().splitlines()[0] if message else ''}"
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    summary = report.summary()
    print(summary)
    (args.out / "summary.txt").write_text(summary.lstrip() + "\n", encoding="utf-8")
    print(f"outputs: {args.out}")
    return EXIT_PASS if report.passed else EXIT_FAIL


if __name__ == "__main__":
    sys.exit(main())
