"""The live page in a real browser: Debian's headless Chromium driven by Playwright for Python
(never `playwright install`: the system's chromium), against a running demo_arm sim_node.
Also writes docs/img/live_view.png when ABD_UPDATE_DOCS_IMG=1 (tools: docs/live.md)."""
from __future__ import annotations

import io
import os
from pathlib import Path
import shutil
import subprocess
import time

import numpy as np
import pytest

from conftest import NodeProcess, Probe, REPO
from live_client import free_port_pair

import foxglove  # noqa: E402,F401 - requirements-live.txt (in requirements-test.txt): no skip

CHROMIUM = os.environ.get('ABD_CHROMIUM', '/usr/bin/chromium')
CHROMIUM_FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic',
                  '--no-first-run', '--disable-background-networking',
                  '--disable-component-update', '--disable-sync',
                  # WebGL on the CPU (SwiftShader): there is no GPU in a headless run
                  '--enable-unsafe-swiftshader', '--use-angle=swiftshader']
WEB = REPO / 'abd_joint_sim' / 'live' / 'web'
DOCS_IMG = REPO / 'docs' / 'img' / 'live_view.png'


def install_three() -> None:
    """three.js for the page, from web/package-lock.json (npm ci, as the MCAP validator)."""
    lock = WEB / 'package-lock.json'
    installed = WEB / 'node_modules' / '.package-lock.json'
    if installed.is_file() and installed.stat().st_mtime >= lock.stat().st_mtime:
        return
    npm = shutil.which('npm')
    if npm is None:
        pytest.fail('npm not found: the live page needs three.js (npm ci in '
                    f'{WEB}); install node.js and npm', pytrace=False)
    result = subprocess.run([npm, 'ci', '--no-audit', '--no-fund', '--ignore-scripts'],
                            cwd=WEB, capture_output=True, text=True, timeout=600,
                            stdin=subprocess.DEVNULL)
    if result.returncode != 0:
        pytest.fail(f'npm ci in {WEB} failed:\n{result.stderr[-2000:]}', pytrace=False)


def browser(playwright, user_data_dir: Path):
    if not os.path.isfile(CHROMIUM):
        pytest.fail(f'{CHROMIUM} not found: the browser test needs Debian\'s chromium '
                    '(sudo apt-get install -y chromium; scripts/test.sh installs it when run '
                    'as root), or set ABD_CHROMIUM to a Chromium binary', pytrace=False)
    return playwright.chromium.launch_persistent_context(
        str(user_data_dir), executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS,
        viewport={'width': 1280, 'height': 720})


def _view_pixels(png: bytes) -> np.ndarray:
    from PIL import Image
    image = np.asarray(Image.open(io.BytesIO(png)).convert('RGB'), dtype=np.int16)
    return image[:, :1280 - 320]                 # the 3D view (the side panel is 320 px)


@pytest.mark.slow
def test_page_draws_the_arm_moving_and_pauses(tmp_path, domain_id):
    from playwright.sync_api import sync_playwright
    from std_msgs.msg import Float64MultiArray
    install_three()
    port = free_port_pair()
    node = NodeProcess.sim_node(tmp_path, domain_id, {
        'scene': 'demo_arm', 'live_port': port, 'start_paused': True})
    probe = Probe(domain_id)
    try:
        end = time.monotonic() + 60
        while f'page http://127.0.0.1:{port + 1}/' not in node.output():
            assert node.alive() and time.monotonic() < end, node.output()[-3000:]
            time.sleep(0.1)
        with sync_playwright() as pw:
            context = browser(pw, tmp_path / 'chromium_profile')
            page = context.pages[0] if context.pages else context.new_page()
            console_errors = []
            page.on('console', lambda m: console_errors.append(m.text) if m.type == 'error'
                    else None)
            page.on('pageerror', lambda e: console_errors.append(str(e)))
            page.goto(f'http://127.0.0.1:{port + 1}/')
            page.wait_for_function('window.live && window.live.connected', timeout=30000)
            page.wait_for_function('window.live.simTime !== null', timeout=30000)
            assert page.inner_text('#state') == 'paused'
            # a torque on the turntable and the shoulder, then Run
            pub = probe.node.create_publisher(Float64MultiArray, 'joint_torque_commands', 10)
            probe.wait_matched_subscriber(pub, log=node)
            pub.publish(Float64MultiArray(data=[3.0, 6.0, 0.0]))
            probe.spin_for(0.3)
            page.click('#unpause')
            page.wait_for_function('window.live.simTime > 0.3', timeout=30000)
            t_a = page.evaluate('window.live.simTime')
            shot_a = page.screenshot()
            page.wait_for_function(f'window.live.simTime >= {t_a + 0.5}', timeout=30000)
            shot_b = page.screenshot()
            t_b = page.evaluate('window.live.simTime')
            assert t_b - t_a >= 0.5
            a, b = _view_pixels(shot_a), _view_pixels(shot_b)
            changed = np.mean(np.any(np.abs(a - b) > 30, axis=2))
            assert changed > 0.002, f'only {changed:.4%} of the view changed in 0.5 s'
            # the page shows the time and the real-time factor
            assert page.inner_text('#sim-time').endswith(' s')
            assert float(page.inner_text('#sim-time').split()[0]) >= t_a
            # Pause stops the time
            page.click('#pause')
            page.wait_for_function("document.getElementById('state').textContent === "
                                   "'paused' || window.live.paused === true", timeout=10000)
            time.sleep(0.5)
            frozen = page.evaluate('window.live.simTime')
            time.sleep(1.0)
            assert page.evaluate('window.live.simTime') == frozen
            assert 'pause' in page.inner_text('#message')
            # Step advances it by one step, Reset brings it to 0
            page.click('#step')
            page.wait_for_function(f'window.live.simTime > {frozen}', timeout=10000)
            page.click('#reset')
            page.wait_for_function('window.live.simTime === 0', timeout=10000)
            assert not console_errors, console_errors
            if os.environ.get('ABD_UPDATE_DOCS_IMG') == '1':
                DOCS_IMG.parent.mkdir(parents=True, exist_ok=True)
                DOCS_IMG.write_bytes(shot_b)
            (tmp_path / 'live_view.png').write_bytes(shot_b)
            context.close()
        assert node.alive()
    finally:
        probe.close()
        code = node.stop()
    assert code == 0, node.output()[-3000:]


def test_page_without_three_says_how_to_install(tmp_path, monkeypatch):
    """The page served without three.js installed names the install command (in a browser)."""
    from playwright.sync_api import sync_playwright
    from abd_joint_sim import Scene
    from abd_joint_sim.live import LiveServer, server
    monkeypatch.setattr(server, 'THREE_DIR', str(tmp_path / 'no_three'))
    scene = Scene.from_file(str(REPO / 'abd_joint_sim' / 'scenes' / 'default.yaml'))
    port = free_port_pair()
    live = LiveServer(scene, [j.name for j in scene.joints], port).start()
    try:
        with sync_playwright() as pw:
            context = browser(pw, tmp_path / 'chromium_profile')
            page = context.pages[0] if context.pages else context.new_page()
            page.goto(f'http://127.0.0.1:{port + 1}/')
            assert 'npm ci' in page.inner_text('body')
            context.close()
    finally:
        live.close()
