"""Headless Chromium for the tests that look at a page as a user does (Debian's ``chromium``, driven by
Playwright).

``.ci/run`` installs Debian's chromium when it is missing and sets ``SRMOSAIC_REQUIRE_BROWSER=1``: there
a missing browser fails the test. On a developer machine without it, the browser tests are skipped
with the line to install it.

    def test_page(chromium):
        page = chromium.new_page()              # a fresh context per test: no shared cookies or cache
        page.goto(url)
"""
from __future__ import annotations

import os
import shutil

import pytest

#: Flags of a headless run on a machine with no network: without the background-networking ones,
#: Chromium's own connections are refused at every start.
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update', '--disable-sync']


def chromium_path() -> str | None:
    for name in ('chromium', 'chromium-browser'):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope='session')
def chromium():
    """A headless Chromium (Playwright ``Browser``) for the worker's whole session."""
    path = chromium_path()
    if path is None:
        if os.environ.get('SRMOSAIC_REQUIRE_BROWSER') == '1':
            pytest.fail('Debian chromium is not installed (apt-get install -y chromium)')
        pytest.skip('headless Chromium not installed: apt-get install -y chromium')
    from playwright.sync_api import sync_playwright
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=path, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()
