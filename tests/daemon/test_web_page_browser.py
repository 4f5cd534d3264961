"""The status page in a real headless Chromium (Debian ``chromium``, driven by
playwright) against the real daemon: the queue, a job's progress advancing, the 3D view
(a WebGL canvas with pixels drawn) and the layer preview, and a job cancelled from the
page. A screenshot of each view goes to ``tests/artifacts/`` (not committed)."""

from __future__ import annotations

import base64
import shutil
import socket
import time
from pathlib import Path

import pytest
from daemon_helpers import broken_stl, tiny_gcode

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run",
        # WebGL without a GPU: SwiftShader, the software renderer Chromium ships
        "--use-angle=swiftshader", "--use-gl=angle", "--enable-unsafe-swiftshader"]

sync_api = pytest.importorskip("playwright.sync_api",
                               reason="playwright is not installed (pip install -e '.[test]')")
if not Path(CHROMIUM).is_file():
    pytest.skip("Chromium is not installed (apt-get install chromium; .ci/run does it)",
                allow_module_level=True)

#: Counts the pixels of a canvas (WebGL or 2D) that differ from the views' background
#: (#1f2533), and those in the "dropped" red of the 3D view.
CANVAS_PIXELS = """(canvas) => {
  const copy = document.createElement('canvas');
  copy.width = canvas.width; copy.height = canvas.height;
  const ctx = copy.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const d = ctx.getImageData(0, 0, copy.width, copy.height).data;
  let drawn = 0, red = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - 0x1f) + Math.abs(d[i + 1] - 0x25) + Math.abs(d[i + 2] - 0x33) > 40) drawn++;
    if (d[i] > 150 && d[i + 1] < 90 && d[i + 2] < 90) red++;
  }
  return {drawn, red, total: d.length / 4};
}"""

#: Drops a file on the drop zone the way a browser does (a DataTransfer with a File).
DROP_FILE = """([name, b64]) => {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const data = new DataTransfer();
  data.items.add(new File([bytes], name));
  const zone = document.getElementById('drop');
  for (const type of ['dragenter', 'dragover', 'drop'])
    zone.dispatchEvent(new DragEvent(type, {dataTransfer: data, bubbles: true, cancelable: true}));
}"""


@pytest.fixture
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def shot(page, name: str) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.evaluate("window.scrollTo(0, 0)")  # the sticky header at the top of the picture
    page.screenshot(path=str(ARTIFACTS / f"page-{name}.png"), full_page=True)


def drop_file(page, name: str, data: bytes) -> None:
    page.evaluate(DROP_FILE, [name, base64.b64encode(data).decode()])


def row(page, name: str):
    return page.locator("#queue li[data-job], #history li[data-job]").filter(has_text=name)


def test_the_page_in_chromium(web_daemon, browser, tmp_path):
    # slow enough a printer that a 1500-move print takes several seconds to stream
    d, port, key = web_daemon(speedup=40.0)
    page = browser.new_page(viewport={"width": 1200, "height": 900})
    page.set_default_timeout(120_000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"http://127.0.0.1:{port}/")

    # no key yet: the page asks for it once, then keeps it
    page.wait_for_selector("#key-dialog[open]")
    page.fill("#key-input", key)
    page.click("#key-save")
    page.wait_for_selector("#link.live")
    assert page.evaluate("localStorage.getItem('preflight.apiKey')") == key
    page.wait_for_selector("#printer-state:has-text('Ready')")

    # the queue: a broken model dropped on the page, left at ready
    page.uncheck("#print-after")
    drop_file(page, "cube.stl", broken_stl(tmp_path / "cube.stl").read_bytes())
    page.wait_for_selector("#upload-answer:has-text('is job 1')")
    row(page, "cube.stl").locator(".badge.ready").wait_for()
    assert row(page, "cube.stl").locator("button[data-action=print]").count() == 1
    shot(page, "queue")

    # its report: the repair in words, the 3D views drawn, the layer preview drawn
    row(page, "cube.stl").locator("button.name").click()
    page.wait_for_selector("#report-summary:has-text('crossing triangles were resolved')")
    page.wait_for_selector("#mesh-note:has-text('Drag to turn')")
    page.wait_for_selector("#layer-label:has-text('layer ')")
    time.sleep(0.5)  # the ResizeObserver's last render
    input_px = page.eval_on_selector("#view-input canvas", CANVAS_PIXELS)
    repaired_px = page.eval_on_selector("#view-repaired canvas", CANVAS_PIXELS)
    layer_px = page.eval_on_selector("#layer-canvas", CANVAS_PIXELS)
    assert input_px["drawn"] > 0.05 * input_px["total"], input_px
    assert repaired_px["drawn"] > 0.05 * repaired_px["total"], repaired_px
    assert input_px["red"] > 0, "the dropped inner wall is not coloured in the input"
    assert repaired_px["red"] == 0, "the repaired mesh shows a dropped face"
    assert layer_px["drawn"] > 0.01 * layer_px["total"], layer_px
    # another layer draws differently (the slider moves through the G-code)
    page.fill("#layer-slider", "0")
    page.wait_for_selector("#layer-label:has-text('layer 1 of')")
    shot(page, "report")

    # progress advancing: a G-code file dropped with "print when ready"
    page.check("#print-after")
    drop_file(page, "long.gcode", tiny_gcode(moves=1500).encode())
    page.wait_for_selector("#now-progress")
    seen: list[float] = []
    end = time.monotonic() + 120
    while len(set(seen)) < 3 and time.monotonic() < end:
        text = page.text_content("#now-progress") or ""
        if "%" in text:
            seen.append(float(text.split("%")[0]))
        time.sleep(0.2)
    assert len(set(seen)) >= 3, f"the progress did not advance: {seen}"
    assert seen == sorted(seen), seen
    assert "left" in page.text_content("#now-progress")
    shot(page, "progress")

    # cancelled from the page
    page.click("#now-body button[data-action=cancel]")
    page.wait_for_selector("#toast:has-text('stopping the print')")
    row(page, "long.gcode").locator(".badge.cancelled").wait_for()
    job = next(j for j in d.jobs() if j.name == "long.gcode")
    d.wait_for(lambda: str(d.journal.get(job.id).state) == "cancelled", what="cancelled")
    page.wait_for_selector("#now-body:has-text('Nothing is printing')")
    shot(page, "cancelled")
    # cancelled part-way: a requeue asks to clear the bed too; declined, nothing is sent
    row(page, "long.gcode").locator("button[data-action=requeue]").click()
    page.wait_for_selector("#confirm-dialog[open]")
    assert "Clear the bed first" in page.text_content("#confirm-text")
    page.click("#confirm-dialog button[value=no]")
    page.wait_for_selector("#confirm-dialog[open]", state="detached")

    page.set_viewport_size({"width": 390, "height": 844})
    time.sleep(0.5)
    shot(page, "phone")
    assert errors == []


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_pause_answer_and_requeue_after_a_crash_in_chromium(web_daemon, browser, tmp_path):
    # a fixed port: the page stays open while the daemon is killed and started again
    port = free_port()
    d, port, key = web_daemon(speedup=40.0, web={"listen": f"127.0.0.1:{port}"})
    page = browser.new_page(viewport={"width": 1000, "height": 900})
    page.set_default_timeout(120_000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.add_init_script(f"localStorage.setItem('preflight.apiKey', {key!r})")
    page.goto(f"http://127.0.0.1:{port}/")
    page.wait_for_selector("#link.live")

    # uploaded with the file chooser; pause answers with what the daemon says
    gcode = tmp_path / "long.gcode"
    gcode.write_text(tiny_gcode(moves=3000))
    page.set_input_files("#file-input", str(gcode))
    page.wait_for_selector("#now-progress")
    page.click("#now-body button[data-action=pause]")
    page.wait_for_selector("#toast.show")
    answer = page.text_content("#toast")
    assert answer and "failed" not in answer.split(":")[0], answer
    page.wait_for_selector("#toast:not(.show)")
    if page.locator("#now-body button[data-action=resume]").count():
        page.click("#now-body button[data-action=resume]")
        page.wait_for_selector("#toast.show")
        answer = page.text_content("#toast")
        assert answer and "failed" not in answer.split(":")[0], answer
        page.wait_for_selector("#toast:not(.show)")

    # the daemon dies mid-print and comes back: the page reconnects by itself
    job = next(j for j in d.jobs() if j.name == "long.gcode")
    d.wait_for(lambda: (d.journal.get(job.id).progress or 0) > 0, what="printing")
    d.kill9()
    page.wait_for_selector("#link:not(.live)")
    d.start()
    page.wait_for_selector("#link.live")
    interrupted = row(page, "long.gcode")
    interrupted.locator(".badge.interrupted").wait_for()

    # requeue asks to clear the bed first; "Cancel" sends nothing
    interrupted.locator("button[data-action=requeue]").click()
    page.wait_for_selector("#confirm-dialog[open]")
    assert "Clear the bed first" in page.text_content("#confirm-text")
    shot(page, "requeue-confirm")
    page.click("#confirm-dialog button[value=no]")
    time.sleep(1.0)  # a requeue would have made it ready within the daemon's 0.2 s poll
    assert str(d.journal.get(job.id).state) == "interrupted"
    shown = page.locator("#toast.show")
    assert shown.count() == 0, page.text_content("#toast")
    interrupted.locator("button[data-action=requeue]").click()
    page.click("#confirm-yes")
    page.wait_for_selector("#toast:has-text('printed again from the start')")
    d.wait_for(lambda: str(d.journal.get(job.id).state) in ("ready", "printing", "done"),
               what="the job requeued")
    assert errors == []
