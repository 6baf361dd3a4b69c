"""End to end in a real browser: headless Chromium (Debian's chromium + chromium-driver, driven by selenium)
answers a short study served on 127.0.0.1, and the database holds exactly what it clicked.

Needs ``chromium`` and ``chromedriver`` on PATH (``make install-browser``). Without them the test is skipped,
except in CI (``CI=true``), where it fails: CI installs them.
"""

from __future__ import annotations

import os
import shutil
import threading
import time

import pytest
from test_study_support import tiny_study

from gnsx.study.app import create_app, make_server
from gnsx.study.assign import questions_for
from gnsx.study.manifest import load_study
from gnsx.study.store import read_answers

pytestmark = pytest.mark.browser
CHOICES = ["left", "right", "left"]


def _browser() -> tuple[str, str]:
    """Paths of chromium and chromedriver, or skip (fail in CI) naming what is missing."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    try:
        import selenium  # noqa: F401
    except ImportError:
        browser = None
    if browser and driver:
        return browser, driver
    reason = "needs chromium, chromedriver and selenium: run `make install-browser` (Debian's packages)"
    if os.environ.get("CI") == "true":
        pytest.fail(f"CI must run the browser test: {reason}")
    pytest.skip(reason)


@pytest.fixture
def server(tmp_path):
    """The web app of a 3-pair study (MPM, original, simplified; one pair per group) on a free port."""
    study = tiny_study(tmp_path, scenes=1, pairs_per_group=1)
    db = tmp_path / "answers.sqlite"
    httpd = make_server(create_app(study, db), "127.0.0.1", 0)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_port}", study, db
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture
def driver():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    browser, chromedriver = _browser()
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                 "--window-size=1200,900"):  # fmt: skip
        options.add_argument(flag)
    chrome = webdriver.Chrome(service=Service(chromedriver), options=options)
    chrome.set_page_load_timeout(20)
    yield chrome
    chrome.quit()


def _detached(element):
    """Wait condition: ``element`` left the page. Selenium's ``staleness_of`` expects a
    StaleElementReferenceException, but chromium sometimes answers a node it just removed with a plain
    WebDriverException ("Node with given id does not belong to the document"), which failed this test about
    once in five runs."""
    from selenium.common.exceptions import WebDriverException

    def check(_driver) -> bool:
        try:
            element.is_enabled()
        except WebDriverException:  # StaleElementReferenceException is one
            return True
        return False

    return check


def test_a_participant_answers_a_study_in_a_real_browser(server, driver):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    url, study_dir, db = server
    wait = WebDriverWait(driver, 10)
    driver.get(url + "/?participant=browser-01")
    assert driver.find_element(By.ID, "participant").get_attribute("value") == "browser-01"
    driver.find_element(By.ID, "start").click()
    tokens = []
    for i, choice in enumerate(CHOICES):
        wait.until(ec.text_to_be_present_in_element((By.ID, "progress"), f"Pair {i + 1} of 3"))
        for side in ("left", "right"):  # both animations arrived and decoded
            loaded = (
                "const m = document.getElementById(arguments[0]); return m.complete && m.naturalWidth > 0;"
            )
            wait.until(lambda d, side=side, js=loaded: d.execute_script(js, f"media-{side}"))
        tokens.append(driver.find_element(By.NAME, "token").get_attribute("value"))
        time.sleep(0.2)  # a participant looks before choosing
        button = driver.find_element(By.ID, f"choose-{choice}")
        button.click()
        wait.until(_detached(button))
    wait.until(ec.presence_of_element_located((By.ID, "done")))
    assert "You answered 3 of 3 pairs" in driver.find_element(By.TAG_NAME, "body").text

    # The browser cannot answer a pair twice, nor one it was never shown.
    post = """const [token, done] = [arguments[0], arguments[arguments.length - 1]];
        fetch('/answer', {method: 'POST', body: new URLSearchParams({token, choice: 'right'})})
            .then(r => done(r.status));"""
    assert driver.execute_async_script(post, tokens[0]) == 409
    assert driver.execute_async_script(post, "X" * 32) == 404

    rows = read_answers(db)
    questions = questions_for(load_study(study_dir), "browser-01")
    assert [row["pair_id"] for row in rows] == [q.pair_id for q in questions]
    for row, question, choice in zip(rows, questions, CHOICES):
        assert row["participant"] == "browser-01" and row["choice"] == choice
        assert (row["left_method"], row["right_method"]) == (question.left, question.right)
        assert row["chosen_method"] == (question.left if choice == "left" else question.right)
        assert 150 <= row["time_ms"] < 30_000  # measured by the page: at least the 0.2 s pause
