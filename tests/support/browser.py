"""A real browser for the live page's tests: Debian's headless Chromium driven by its
chromium-driver through Selenium (scripts/setup installs both), kept off every network but
loopback: a dead proxy for anything that is not loopback, Chromium's background services off,
and Selenium Manager (which would look for drivers online) never asked."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
DRIVER = "/usr/bin/chromedriver"
#: a port nothing listens on: a request that would leave the host fails here
DEAD_PROXY = "http://127.0.0.1:9"
FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
         "--no-default-browser-check", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--disable-default-apps", "--disable-extensions", "--metrics-recording-only",
         "--disable-features=Translate,OptimizationHints,MediaRouter,DialMediaRouteProvider",
         f"--proxy-server={DEAD_PROXY}", "--window-size=1600,1250", "--force-device-scale-factor=1"]


def browser_missing() -> str | None:
    """Why no browser test can run here (None: it can)."""
    for path in (CHROMIUM, DRIVER):
        if not (os.path.exists(path) or shutil.which(Path(path).name)):
            return f"{path} is missing: scripts/setup installs chromium and chromium-driver (Debian)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e .[test])"
    return None


def chromium():
    """A headless Chromium (selenium WebDriver); quit it when done."""
    why = browser_missing()
    if why:
        pytest.skip(why)
    os.environ["SE_OFFLINE"] = "true"          # Selenium Manager: never online
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    for flag in FLAGS:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(DRIVER if os.path.exists(DRIVER) else shutil.which("chromedriver")),
                              options=options)
    driver.set_script_timeout(30)
    return driver


def wait_until(driver, script: str, timeout: float = 30.0, why: str = ""):
    """Run ``script`` (a JS expression's body: ``return ...``) until it returns something true;
    that value. Fails naming ``why`` after ``timeout`` s."""
    from selenium.webdriver.support.ui import WebDriverWait
    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(lambda d: d.execute_script(script))
    except Exception as exc:
        raise AssertionError(f"{why or script}: not within {timeout} s ({type(exc).__name__})") from None
