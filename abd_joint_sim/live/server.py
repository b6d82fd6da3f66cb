"""The live server: a Foxglove WebSocket server (``foxglove-sdk``) and the page that watches it.

:class:`LiveServer` serves ``/scene``, ``/tf``, ``/joint_states`` and ``/status`` (JSON, stamped
in simulated time), the server time and the owner's services ``pause``, ``unpause``,
``step``, ``reset`` (docs/live.md, "What is served"). A publish happens after a step, at most
:data:`LIVE_RATE_HZ` times per wall second and only while a client subscribes. The page: a
small HTTP server on ``port + 1`` serving ``web/index.html`` and three.js from
``web/node_modules`` (``npm ci`` in ``web/``; without it the page says how to install it).
"""
from __future__ import annotations

import http.server
import json
import math
import os
import threading
import time
from typing import Any, Callable, Optional

import numpy as np

from . import schemas
from .scene import FrameBuilder, scene_entities, scene_update_bytes, stamp

LIVE_RATE_HZ = 60.0
"""Most publishes per second of wall time."""
SCENE_PERIOD = 1.0
"""Wall seconds between repeats of the SceneUpdate while someone subscribes."""
RTF_WINDOW = 0.5
"""Wall seconds over which the real-time factor is measured."""
DEFAULT_HOST = '127.0.0.1'
TOPIC_SCENE, TOPIC_TF, TOPIC_JOINT_STATES, TOPIC_STATUS = (
    '/scene', '/tf', '/joint_states', '/status')
SERVICES = ('pause', 'unpause', 'step', 'reset')
WEB_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'web')
THREE_DIR = os.path.join(WEB_DIR, 'node_modules', 'three')
INSTALL_HINT = f'npm ci --ignore-scripts --prefix {WEB_DIR}'


class LiveError(Exception):
    """The live server cannot start (one line naming why)."""


def check_port(value: Any, what: str = 'live_port') -> int:
    """`value` as a TCP port 1..65535 (0 = off is the caller's business); ValueError naming
    `what` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise ValueError(f'{what}: expected a whole number 1..65535 (0 = off), got {value!r}')
    value = int(value)
    if not 1 <= value <= 65535:
        raise ValueError(f'{what}: {value} is outside the TCP ports 1..65535 (0 = off)')
    return value


class LiveServer:
    """A live view of a simulation (module docstring): `scene`'s bodies, `joint_names` in
    the world's order, on `port` (1..65535; the page, if `page`, on ``port + 1``) of `host`
    (anything but loopback logs a warning). `services`: name (of :data:`SERVICES`) ->
    callable() -> (success, message); `log`: callable(level, text) for the owner's log;
    `playback`: a replay's pacer, answering Foxglove's playback control over
    0..`playback_end_ns` of simulated time (None: a live run)."""

    def __init__(self, scene: Any, joint_names, port: int, host: str = DEFAULT_HOST,
                 world_frame: str = 'world',
                 services: Optional[dict[str, Callable[[], tuple[bool, str]]]] = None,
                 name: str = 'abd_joint_sim', source: str = 'sim_node', page: bool = True,
                 log: Optional[Callable[[str, str], None]] = None, playback: Any = None,
                 playback_end_ns: int = 0):
        self.port = check_port(port)
        self.host = (host or DEFAULT_HOST).strip()
        self.name, self.source = name, source
        self.log = log or (lambda level, text: None)
        self.joint_names = list(joint_names)
        self.frames = FrameBuilder(scene, world_frame)
        self.entities = scene_entities(scene)
        self.services = dict(services or {})
        self.playback = playback
        self.playback_end_ns = int(playback_end_ns)
        self.page = page
        self.http_port: Optional[int] = None
        self.published = 0
        self.refresh_due = False
        """A client subscribed: the owner publishes the current state even while paused."""
        self._subscriptions = 0
        self._sub_lock = threading.Lock()
        self._scene_due = True
        self._scene_wall = self._last_wall = -math.inf
        self._rtf = 0.0
        self._rtf_anchor: Optional[tuple[float, float]] = None
        self._names_json = json.dumps(self.joint_names)
        self._server = self._http = None

    # ------------------------------------------------------------------ start/stop ----
    def start(self) -> 'LiveServer':
        """Listen; LiveError (one line) if the SDK is missing or the port is taken."""
        try:
            import foxglove
            from foxglove import Schema
            from foxglove.websocket import (Capability, MessageSchema, Service,
                                            ServiceSchema)
        except ImportError:
            raise LiveError('the live view needs the foxglove-sdk package: '
                            'pip install -r requirements-live.txt') from None
        self._context = foxglove.Context()

        def schema(s: dict) -> Schema:
            return Schema(name=s['title'], encoding='jsonschema', data=schemas.text(s))
        self._scene_ch, self._tf_ch, self._js_ch, self._status_ch = (
            foxglove.Channel(topic, schema=schema(s), message_encoding='json',
                             context=self._context)
            for topic, s in ((TOPIC_SCENE, schemas.SCENE_UPDATE),
                             (TOPIC_TF, schemas.FRAME_TRANSFORMS),
                             (TOPIC_JOINT_STATES, schemas.JOINT_STATES),
                             (TOPIC_STATUS, schemas.STATUS)))
        trigger = ServiceSchema('std_srvs/srv/Trigger', **{
            k: MessageSchema(encoding='json', schema=schema(s))
            for k, s in (('request', schemas.TRIGGER_REQUEST),
                         ('response', schemas.TRIGGER_RESPONSE))})
        services = [Service(name, schema=trigger, handler=self._service_handler(name))
                    for name in SERVICES if name in self.services]
        if not (self.host in ('127.0.0.1', 'localhost', '::1') or self.host.startswith('127.')):
            self.log('warn', f'live view bound to {self.host}:{self.port}: anyone who can '
                     'reach this address sees the run and can pause, step and reset it')
        try:
            self._server = foxglove.start_server(
                name=self.name, host=self.host, port=self.port, context=self._context,
                capabilities=[Capability.Time] + ([Capability.Services] if services else []),
                server_listener=self, supported_encodings=['json'],
                services=services or None,
                playback_time_range=((0, self.playback_end_ns) if self.playback is not None
                                     else None))
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError/OSError
            why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise LiveError(f'live_port {self.port}: cannot listen on {self.host}:{self.port} '
                            f'({why})') from None
        if self.page:
            self._start_page()
        return self

    def _start_page(self) -> None:
        port = self.port + 1
        if port > 65535:
            self.log('warn', f'no page: live_port {self.port} leaves no next port for it')
            return
        handler = type('Handler', (_PageHandler,), {'live': self})
        try:
            self._http = _PageServer((self.host, port), handler)
        except OSError as exc:
            why = exc.strerror or exc
            self.log('warn', f'live page not served: port {port} on {self.host} ({why}); '
                     f'Foxglove can still connect to ws://{self.host}:{self.port}')
            return
        self.http_port = port
        threading.Thread(target=self._http.serve_forever, kwargs={'poll_interval': 0.2},
                         name='live_page', daemon=True).start()

    def describe(self) -> str:
        page = (f'; page http://{self.host}:{self.http_port}/' if self.http_port else '')
        return f'live view ws://{self.host}:{self.port} (Foxglove WebSocket){page}'

    def close(self) -> None:
        """Stop both servers (idempotent)."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()
        http, self._http = self._http, None
        if http is not None:
            http.shutdown()
            http.server_close()

    # ---------------------------------------- the SDK's server listener: subscriptions ----
    def on_subscribe(self, client, channel) -> None:
        with self._sub_lock:
            self._subscriptions += 1
            if channel.topic == TOPIC_SCENE:
                self._scene_due = True
            self.refresh_due = True

    def on_unsubscribe(self, client, channel) -> None:
        with self._sub_lock:
            self._subscriptions = max(0, self._subscriptions - 1)

    def on_playback_control_request(self, request):
        return None if self.playback is None else self.playback.on_playback_control_request(request)

    # ------------------------------------------------------------------- publishing ----
    @property
    def wanted(self) -> bool:
        """Someone subscribes to a channel (the SDK's subscribe/unsubscribe callbacks)."""
        return self._subscriptions > 0

    def publish_loop(self, loop: Any, force: bool = False) -> bool:
        """Publish the state of `loop` (a ``SimLoop``) if someone subscribes and the rate
        allows (`force`: the rate does not apply). Returns whether it published."""
        if self._subscriptions <= 0:
            self.refresh_due = False
            return False
        now = time.monotonic()
        if not force and now - self._last_wall < 1.0 / LIVE_RATE_HZ:
            return False
        self.refresh_due = False
        self._last_wall = now
        world = loop.world
        t = float(world.time)
        t_ns = int(round(t * 1e9))
        poses = self.frames.body_poses(world.body_pose)
        if poses is None:
            return False
        self._measure_rtf(now, t)
        ts = stamp(t_ns)
        if self._scene_due or now - self._scene_wall >= SCENE_PERIOD:
            self._scene_due = False
            self._scene_wall = now
            if self._scene_ch.has_sinks():
                self._scene_ch.log(scene_update_bytes(self.entities, t_ns), log_time=t_ns)
        if self._tf_ch.has_sinks():
            self._tf_ch.log(self.frames.transforms(t_ns, poses), log_time=t_ns)
        if self._js_ch.has_sinks():
            self._js_ch.log(
                '{"timestamp":%s,"name":%s,"position":%s,"velocity":%s,"effort":%s}' % (
                    json.dumps(ts), self._names_json, _floats(world.joint_angles()),
                    _floats(world.joint_velocities()), _floats(world.applied_torques())),
                log_time=t_ns)
        if self._status_ch.has_sinks():
            last = getattr(world, 'last_step', None)
            self._status_ch.log({
                'timestamp': ts, 'sim_time': t, 'steps': int(loop.steps),
                'paused': bool(loop.paused), 'time_step': float(world.dt),
                'real_time_factor': self._rtf,
                'newton_iterations': int(getattr(last, 'newton_iterations', 0)),
                'converged': bool(getattr(last, 'converged', True)),
                'max_joint_separation': float(getattr(last, 'max_joint_separation', 0.0)),
                'fault': loop.fault or '', 'source': self.source,
                'wall_time': time.time()}, log_time=t_ns)
        if self._server is not None:
            self._server.broadcast_time(t_ns)
        self.published += 1
        return True

    def _measure_rtf(self, now: float, t: float) -> None:
        anchor = self._rtf_anchor
        if anchor is None or t < anchor[1]:
            self._rtf_anchor = (now, t)
            return
        if now - anchor[0] >= RTF_WINDOW:
            self._rtf = (t - anchor[1]) / (now - anchor[0])
            self._rtf_anchor = (now, t)

    # ------------------------------------------------------------------- services ----
    def _service_handler(self, name: str):
        call = self.services[name]

        def handler(request) -> bytes:
            try:
                ok, message = call()
            except Exception as exc:  # noqa: BLE001 - answered, not raised into the SDK
                ok, message = False, f'{type(exc).__name__}: {exc}'
            if name in ('pause', 'unpause'):
                self._rtf_anchor = None     # paused time is no slowness
            return json.dumps({'success': bool(ok), 'message': str(message)}).encode()
        return handler


def _floats(values) -> str:
    return json.dumps(np.asarray(values, dtype=float).tolist())


class _PageServer(http.server.ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = False     # a second server on the same port is refused


_TYPES = {'.html': 'text/html; charset=utf-8', '.js': 'text/javascript; charset=utf-8',
          '.json': 'application/json', '.css': 'text/css'}


class _PageHandler(http.server.BaseHTTPRequestHandler):
    """GET / (the page), /live.js, /config.json, /three/<file of the three package>."""

    live: LiveServer
    server_version = 'abd_joint_sim-live'

    def log_message(self, format, *args):  # noqa: A002 - quiet: the node has its own log
        pass

    def do_GET(self):  # noqa: N802 - http.server's name
        path = self.path.split('?', 1)[0]
        if path in ('/', '/index.html'):
            if os.path.isfile(os.path.join(THREE_DIR, 'build', 'three.module.js')):
                return self._file(os.path.join(WEB_DIR, 'index.html'))
            return self._send(200, _TYPES['.html'], _NO_THREE.format(
                hint=INSTALL_HINT, port=self.live.port, host=self.live.host).encode())
        if path == '/live.js':
            return self._file(os.path.join(WEB_DIR, 'live.js'))
        if path == '/config.json':
            return self._send(200, _TYPES['.json'], json.dumps({
                'ws_port': self.live.port, 'source': self.live.source,
                'name': self.live.name}).encode())
        if path.startswith('/three/'):
            target = os.path.realpath(os.path.join(THREE_DIR, path[len('/three/'):]))
            if target.startswith(os.path.realpath(THREE_DIR) + os.sep):
                return self._file(target)
        return self._send(404, 'text/plain', b'not found\n')

    def _file(self, path: str) -> None:
        try:
            with open(path, 'rb') as f:
                data = f.read()
        except OSError:
            return self._send(404, 'text/plain', b'not found\n')
        self._send(200, _TYPES.get(os.path.splitext(path)[1], 'application/octet-stream'), data)

    def _send(self, code: int, ctype: str, body: bytes) -> None:
        self.send_response(code)
        self.send_header('Content-Type', ctype)
        self.send_header('Content-Length', str(len(body)))
        self.send_header('Cache-Control', 'no-store')
        self.end_headers()
        if self.command != 'HEAD':
            self.wfile.write(body)


_NO_THREE = """<!doctype html><meta charset="utf-8"><title>abd_joint_sim live</title>
<body style="font-family:sans-serif;max-width:50em;margin:2em auto">
<h1>abd_joint_sim live view</h1>
<p id="missing">The page needs three.js, which is not installed. Install it once with</p>
<pre>{hint}</pre>
<p>(the test set-up, <code>bash scripts/test.sh</code>, does it too), then reload.
Meanwhile Foxglove can connect to <code>ws://{host}:{port}</code>.</p></body>
"""
