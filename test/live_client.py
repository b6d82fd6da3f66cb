"""A Foxglove WebSocket client for the tests (protocol foxglove.sdk.v1, JSON messages), on the
`websockets` package's synchronous client: the live server seen as Foxglove sees it."""
from __future__ import annotations

import json
import socket
import struct
import time
from typing import Optional

from websockets.sync.client import connect

SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']
# the protocol's playback control (client opcode 3) and playback state (server opcode 5)
PLAYBACK_COMMANDS = ('play', 'pause')
PLAYBACK_STATUS = ('playing', 'paused', 'buffering', 'ended')


def free_port_pair() -> int:
    """A port p with p and p + 1 free right now (the live server and its page)."""
    for _ in range(50):
        with socket.socket() as s:
            s.bind(('127.0.0.1', 0))
            port = s.getsockname()[1]
        if port >= 65535:
            continue
        with socket.socket() as s:
            try:
                s.bind(('127.0.0.1', port + 1))
            except OSError:
                continue
        return port
    raise RuntimeError('no free pair of ports')


class LiveClient:
    """Connects, reads serverInfo and the advertisements, subscribes, decodes messages."""

    def __init__(self, port: int, timeout: float = 10.0, host: str = '127.0.0.1'):
        end = time.monotonic() + timeout
        while True:
            try:
                self._cm = connect(f'ws://{host}:{port}', subprotocols=SUBPROTOCOLS,
                                   open_timeout=2.0, max_size=None)
                self.ws = self._cm.__enter__()
                break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.1)
        self.server_info: dict = {}
        self.channels: dict[int, dict] = {}
        self.services: dict[str, dict] = {}
        self.times: list[int] = []
        self.statuses: list[dict] = []
        self.playback_states: list[dict] = []
        self._subs: dict[int, str] = {}
        self._next_sub = 1
        self._next_call = 1
        self._responses: dict[int, dict] = {}
        self._backlog: list[tuple[str, int, dict]] = []
        end = time.monotonic() + timeout
        while time.monotonic() < end and not (
                self.server_info and self.channels and (
                    self.services or 'services' not in self.server_info['capabilities'])):
            self._read(0.5)

    def topics(self) -> set:
        return {c['topic'] for c in self.channels.values()}

    def subscribe(self, *topics: str) -> None:
        subs = []
        for ch in self.channels.values():
            if not topics or ch['topic'] in topics:
                subs.append({'id': self._next_sub, 'channelId': ch['id']})
                self._subs[self._next_sub] = ch['topic']
                self._next_sub += 1
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def _read(self, timeout: float) -> Optional[tuple[str, int, dict]]:
        """One frame; a message on a subscription is returned (topic, log time, decoded)."""
        try:
            frame = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return None
        if isinstance(frame, str):
            msg = json.loads(frame)
            op = msg.get('op')
            if op == 'serverInfo':
                self.server_info = msg
            elif op == 'advertise':
                for ch in msg['channels']:
                    self.channels[ch['id']] = ch
            elif op == 'advertiseServices':
                for sv in msg['services']:
                    self.services[sv['name']] = sv
            elif op == 'status':
                self.statuses.append(msg)
            return None
        opcode = frame[0]
        if opcode == 1:
            sub, log_time = struct.unpack_from('<IQ', frame, 1)
            return self._subs.get(sub, '?'), log_time, json.loads(frame[13:])
        if opcode == 2:
            self.times.append(struct.unpack_from('<Q', frame, 1)[0])
        elif opcode == 3:
            _sid, call, n = struct.unpack_from('<III', frame, 1)
            self._responses[call] = json.loads(frame[13 + n:])
        elif opcode == 5:
            status, now, speed, did_seek, n = struct.unpack_from('<BQfBI', frame, 1)
            self.playback_states.append({
                'status': PLAYBACK_STATUS[status], 'current_time': now, 'speed': speed,
                'did_seek': bool(did_seek), 'request_id': frame[19:19 + n].decode()})
        return None

    def next_message(self, timeout: float = 5.0, topic: Optional[str] = None):
        """(topic, log time ns, message) of the next message (on `topic`), or None."""
        for i, item in enumerate(self._backlog):
            if topic is None or item[0] == topic:
                return self._backlog.pop(i)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            item = self._read(max(end - time.monotonic(), 0.001))
            if item is None:
                continue
            if topic is None or item[0] == topic:
                return item
            self._backlog.append(item)
        return None

    def messages_for(self, seconds: float) -> list:
        """Every message received within `seconds`."""
        out = list(self._backlog)
        self._backlog.clear()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            item = self._read(max(end - time.monotonic(), 0.001))
            if item is not None:
                out.append(item)
        return out

    def call(self, service: str, timeout: float = 10.0) -> dict:
        """Call a service (JSON request {}), return its decoded response."""
        sid = self.services[service]['id']
        call = self._next_call
        self._next_call += 1
        self.ws.send(struct.pack('<BIII', 2, sid, call, 4) + b'json' + b'{}')
        end = time.monotonic() + timeout
        while call not in self._responses:
            if time.monotonic() > end:
                raise AssertionError(f'no answer from service {service!r}')
            item = self._read(0.2)
            if item is not None:
                self._backlog.append(item)
        return self._responses.pop(call)

    def playback(self, command: str, speed: float = 1.0, seek_ns: Optional[int] = None,
                 timeout: float = 10.0) -> dict:
        """Send Foxglove's playback control request (command 'play' or 'pause', a speed, an
        optional seek time) and return the server's playback state answering it."""
        request_id = f'req{self._next_call}'
        self._next_call += 1
        self.ws.send(struct.pack('<BBfBQI', 3, PLAYBACK_COMMANDS.index(command), speed,
                                 seek_ns is not None, seek_ns or 0, len(request_id))
                     + request_id.encode())
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for state in self.playback_states:
                if state['request_id'] == request_id:
                    return state
            item = self._read(0.2)
            if item is not None:
                self._backlog.append(item)
        raise AssertionError(f'no playback state answering {command!r}')

    def close(self) -> None:
        self._cm.__exit__(None, None, None)
