"""The web page in real headless Chromium: an artist's session, from the scene on disk to the EXR downloaded."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import httpx
import pytest

from forest.service.app import ServiceConfig, create_app

from test_service_support import ServerThread, tiny_config

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"

pytestmark = pytest.mark.skipif(
    not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()),
    reason="Debian packages chromium and chromium-driver are not installed",
)


@pytest.fixture()
def browser(tmp_path):
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    os.environ["SE_OFFLINE"] = "true"  # never let Selenium fetch a browser or driver
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1280,1600",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(60)
    downloads = tmp_path / "downloads"
    downloads.mkdir()
    driver.execute_cdp_cmd("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    driver.downloads = downloads
    try:
        yield driver
    finally:
        driver.quit()


def wait(predicate, timeout=120.0, step=0.05):
    deadline = time.monotonic() + timeout
    while True:
        v = predicate()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("the page did not get there in time")
        time.sleep(step)


def mtime(path) -> int | None:
    """The file's modification time, or None while it is absent (a requeued frame's file is replaced)."""
    try:
        return path.stat().st_mtime_ns
    except FileNotFoundError:
        return None


def js(d, script, *args):
    return d.execute_script(script, *args)


def test_submit_the_demo_with_its_maps_folder_watch_it_refine_and_download_an_exr(browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    from forest.example_scenes import copy_example

    # the demo as an artist has it on disk: demo.toml with its maps/ folder beside it
    scene = copy_example("demo", tmp_path / "scene")
    data = tmp_path / "data"
    app = create_app(ServiceConfig(data_dir=data, workers=1, seed_examples=False))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url) as c:
        d = browser
        d.get(srv.url + "/")
        wait(lambda: "executor" in d.find_element(By.ID, "health").text)
        assert c.get("/assets").json() == []  # nothing of the demo's on the service yet

        d.find_element(By.ID, "config-file").send_keys(str(scene))
        wait(lambda: 'heightmap = "maps/demo_height.png"' in d.find_element(By.ID, "config").get_attribute("value"))
        d.find_element(By.ID, "folder-files").send_keys(str(scene.parent / "maps"))
        wait(lambda: d.find_element(By.ID, "asset-status").get_attribute("data-uploaded") == "5")
        names = sorted(a["name"] for a in c.get("/assets").json())
        assert names == sorted(f"maps/{p.name}" for p in (scene.parent / "maps").iterdir())

        # a three-frame fly-through, small enough for a test; the config itself is submitted unchanged
        Select(d.find_element(By.ID, "kind")).select_by_value("flythrough")
        for field, value in (("frames", "1-3"), ("width", "160"), ("height", "90"), ("spp", "32"), ("count", "3000")):
            d.find_element(By.ID, field).send_keys(value)
        d.find_element(By.ID, "submit").click()
        jid = wait(lambda: js(d, "return location.hash").partition("#job=")[2] or None, timeout=30)
        job_dir = data / "jobs" / jid
        assert (job_dir / "maps" / "demo_height.png").read_bytes() == (
            scene.parent / "maps" / "demo_height.png"
        ).read_bytes()

        # watch it refine: the preview is replaced pass after pass while the frames render
        seen = set()

        def refined():
            s = js(
                d,
                "const i = document.getElementById('job-preview');"
                "return {state: document.getElementById('job-view').dataset.state, passes: i.dataset.passes,"
                " shown: !i.hidden && i.complete && i.naturalWidth, label: document.getElementById('pass-label').textContent};",
            )
            if s["shown"] and s["passes"]:
                seen.add((s["label"], s["passes"]))
            return s["state"] == "succeeded"

        wait(refined, timeout=300)
        passes = {p for _, p in seen}
        assert len(passes) >= 2 and any(label.startswith("frame ") for label, _ in seen), seen
        # the final image replaces the last pass's: wait for it to load rather than read it mid-swap
        wait(lambda: js(d, "return document.getElementById('job-preview').naturalWidth") == 160, timeout=30)

        # the frame grid: one cell per frame, coloured by state, thumbnails loaded
        grid = "return [...document.querySelectorAll('#frame-grid .cell')].map(c => [c.dataset.frame, c.dataset.state])"
        wait(lambda: js(d, grid) == [["1", "done"], ["2", "done"], ["3", "done"]])
        cells_js = (
            "return [...document.querySelectorAll('#frame-grid .cell')].map(c => [c.querySelector('img').naturalWidth,"
            " getComputedStyle(c).borderTopColor])"
        )

        def cells_ready() -> bool:
            # thumbnails load and the border colour transitions after the state changes: wait for both (on a
            # loaded machine they lag the grid's state by a moment)
            cells = js(d, cells_js)
            return all(w > 0 for w, _ in cells) and len({colour for _, colour in cells}) == 1

        wait(cells_ready, timeout=30)
        d.find_element(By.CSS_SELECTOR, "#frame-grid .cell[data-frame='2']").click()
        wait(lambda: d.find_element(By.ID, "frame-title").text == "Frame 2")
        d.save_screenshot(str(tmp_path / "job-page.png"))

        # download the EXR of frame 2: the browser saves the bytes the render wrote
        d.find_element(By.CSS_SELECTOR, "#frame-links a.exr").click()
        saved = wait(lambda: next(iter(d.downloads.glob("frame_0002.exr")), None), timeout=30)
        wait(lambda: not list(d.downloads.glob("*.crdownload")), timeout=30)
        assert saved.read_bytes() == (job_dir / "out" / "frame_0002.exr").read_bytes()

        # the flip-book plays the finished frames
        assert d.find_element(By.ID, "flipbook-panel").is_displayed()
        d.find_element(By.ID, "flip-play").click()
        shown = set()
        wait(
            lambda: shown.add(d.find_element(By.ID, "flip-image").get_attribute("data-frame")) or len(shown) >= 3,
            timeout=20,
        )
        d.find_element(By.ID, "flip-play").click()

        # downloads offer every output
        wait(lambda: "EXR frames (zip)" in d.find_element(By.ID, "downloads").text)

        # back to the table: the job by its name, counts that add up, the worker that ran it
        d.find_element(By.CSS_SELECTOR, "#job-head a.back").click()
        wait(lambda: d.find_element(By.ID, "list-view").is_displayed())
        row = wait(lambda: d.find_elements(By.CSS_SELECTOR, f"#jobs tr[data-id='{jid}']"))[0]
        assert "demo" in row.text and "SUCCEEDED" in row.text.upper() and "3/3 frames" in row.text
        wait(
            lambda: (
                "1 succeeded" in d.find_element(By.ID, "counts").text
                and "= 1 job" in d.find_element(By.ID, "counts").text
            )
        )
        assert "local-0" in d.find_element(By.ID, "workers").text
        d.find_element(By.ID, "filter-name").send_keys("no such name")
        wait(lambda: d.find_element(By.ID, "no-jobs").is_displayed())
        d.find_element(By.ID, "filter-name").clear()
        Select(d.find_element(By.ID, "filter-state")).select_by_visible_text("failed")
        wait(lambda: d.find_element(By.ID, "no-jobs").is_displayed())
        Select(d.find_element(By.ID, "filter-state")).select_by_visible_text("succeeded")
        wait(lambda: d.find_elements(By.CSS_SELECTOR, f"#jobs tr[data-id='{jid}']"))
        d.save_screenshot(str(tmp_path / "list.png"))


def test_cancel_and_resume_from_the_job_page(browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    data = tmp_path / "data"
    with ServerThread(create_app(ServiceConfig(data_dir=data, workers=1, seed_examples=False))) as srv:
        d = browser
        d.get(srv.url + "/")
        wait(lambda: "executor" in d.find_element(By.ID, "health").text)
        d.execute_script("document.getElementById('config').value = arguments[0]", tiny_config())
        Select(d.find_element(By.ID, "kind")).select_by_value("flythrough")
        d.find_element(By.ID, "name").send_keys("long one")
        for field, value in (("frames", "1-6"), ("frames-per-task", "6"), ("spp", "128"), ("width", "96")):
            d.find_element(By.ID, field).send_keys(value)
        d.find_element(By.ID, "submit").click()
        wait(lambda: d.find_element(By.ID, "job-state").get_attribute("textContent") == "running")
        assert d.find_element(By.ID, "job-title").text.startswith("long one")
        d.find_element(By.ID, "job-cancel").click()
        wait(lambda: d.find_element(By.ID, "job-state").get_attribute("textContent") == "canceled", timeout=30)
        assert d.find_element(By.ID, "job-cancel").get_attribute("disabled")
        wait(
            lambda: "canceled" in d.find_element(By.ID, "job-log").text or d.find_element(By.ID, "log-refresh").click()
        )
        d.find_element(By.ID, "job-resume").click()
        wait(lambda: d.find_element(By.ID, "job-state").get_attribute("textContent") == "succeeded", timeout=180)
        wait(lambda: "6 / 6" in d.find_element(By.ID, "job-facts").text, timeout=10)
        wait(lambda: "EXR frames (zip)" in d.find_element(By.ID, "downloads").text, timeout=10)

        # render one frame again from its cell in the grid
        jid = js(d, "return location.hash").partition("#job=")[2]
        exr = data / "jobs" / jid / "out" / "frame_0003.exr"
        before = exr.stat().st_mtime_ns
        wait(lambda: d.find_elements(By.CSS_SELECTOR, "#frame-grid .cell[data-frame='3'][data-state='done']"))
        d.find_element(By.CSS_SELECTOR, "#frame-grid .cell[data-frame='3']").click()
        wait(lambda: d.find_element(By.ID, "frame-title").text == "Frame 3")
        d.find_element(By.CSS_SELECTOR, "#frame-links button.requeue").click()
        wait(lambda: mtime(exr) not in (None, before), timeout=120)
        wait(lambda: d.find_element(By.ID, "job-state").get_attribute("textContent") == "succeeded", timeout=60)
