"""The web page in real headless Chromium: submit, watch progress, see the image, cancel."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

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
        "--window-size=1200,1400",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


def wait(predicate, timeout=90.0, step=0.05):
    deadline = time.monotonic() + timeout
    while True:
        v = predicate()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("the page did not get there in time")
        time.sleep(step)


def card_state(driver, job_id):
    return driver.execute_script(
        "const el = document.querySelector(`article.job[data-id='${arguments[0]}']`);"
        "return el ? {state: el.dataset.state, bar: el.querySelector('.bar').value,"
        " msg: el.querySelector('.message').textContent,"
        " img: el.querySelector('img.preview').hidden ? 0 : el.querySelector('img.preview').naturalWidth} : null;",
        job_id,
    )


def newest_job_id(driver, previous: set[str]) -> str:
    def find():
        ids = driver.execute_script("return [...document.querySelectorAll('article.job')].map(e => e.dataset.id)")
        new = [i for i in ids if i not in previous]
        return new[0] if new else None

    return wait(find, timeout=30)


def test_page_submit_watch_see_cancel(browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    with ServerThread(create_app(ServiceConfig(data_dir=tmp_path / "data", workers=1))) as srv:
        d = browser
        d.get(srv.url + "/")
        wait(lambda: "executor" in d.find_element(By.ID, "health").text)

        # load the scene from a file, as a user picking it from disk would
        scene = tmp_path / "tiny.toml"
        scene.write_text(tiny_config())
        d.find_element(By.ID, "config-file").send_keys(str(scene))
        wait(lambda: "[terrain]" in d.find_element(By.ID, "config").get_attribute("value"))

        # a twelve-frame fly-through in one task: progress moves a frame at a time
        Select(d.find_element(By.ID, "kind")).select_by_value("flythrough")
        d.find_element(By.ID, "frames").send_keys("1-12")
        d.find_element(By.ID, "frames-per-task").send_keys("12")
        d.find_element(By.ID, "width").send_keys("40")
        d.find_element(By.ID, "height").send_keys("30")
        d.find_element(By.ID, "submit").click()
        job = newest_job_id(d, set())
        seen = []

        def done():
            s = card_state(d, job)
            if s:
                seen.append(s)
            return s and s["state"] in ("succeeded", "failed", "canceled") and (s["img"] or s["state"] != "succeeded")

        wait(done)
        assert seen[-1]["state"] == "succeeded", seen[-1]
        bars = [s["bar"] for s in seen]
        assert any(0 < b < 1 for b in bars), bars  # watched it progress
        assert bars == sorted(bars) and bars[-1] == 1
        assert "running" in {s["state"] for s in seen}
        assert seen[-1]["img"] == 40  # the latest pass is shown
        wait(
            lambda: (
                d.execute_script(
                    "const i = document.querySelector(`#gallery figure[data-id='${arguments[0]}'] img`);"
                    "return i && i.complete && i.naturalWidth",
                    job,
                )
                == 40
            )
        )
        caption = d.find_element(By.CSS_SELECTOR, f"#gallery figure[data-id='{job}'] figcaption").text
        assert "40×30" in caption and "trees" in caption
        d.save_screenshot(str(tmp_path / "page.png"))

        # a long one, canceled from the page
        d.find_element(By.ID, "frames").clear()
        d.find_element(By.ID, "frames").send_keys("1-8")
        d.find_element(By.ID, "frames-per-task").clear()
        d.find_element(By.ID, "frames-per-task").send_keys("8")
        d.find_element(By.ID, "submit").click()
        job2 = newest_job_id(d, {job})
        wait(lambda: (card_state(d, job2) or {}).get("state") == "running")
        d.find_element(By.CSS_SELECTOR, f"article.job[data-id='{job2}'] button.cancel").click()
        wait(lambda: (card_state(d, job2) or {}).get("state") == "canceled", timeout=30)
        assert d.find_element(By.CSS_SELECTOR, f"article.job[data-id='{job2}'] button.cancel").get_attribute("disabled")
        # and the log button shows the job's log
        d.find_element(By.CSS_SELECTOR, f"article.job[data-id='{job2}'] button.show-log").click()
        wait(lambda: "canceled" in d.find_element(By.CSS_SELECTOR, f"article.job[data-id='{job2}'] pre.log").text)
