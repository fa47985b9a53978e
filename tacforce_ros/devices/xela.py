"""XELA uSkin through xela_server's WebSocket: JSON message codec and a reconnecting client.

Wire facts (docs/PROTOCOLS.md section 1): JSON text frames, a welcome frame first, then
``"type": "routine"`` frames (~100/s) with a ``message`` counter, server ``time`` (Unix s) and one
object per sensor. The Allegro set is ONE sensor of 368 taxels whose ``data`` is 3 x 368 values,
X,Y,Z per taxel in XELA's flat (scan) order, as comma-separated 4-digit hex (or, on some server
versions, a JSON list of ints: both accepted); ``temp`` is Kelvin per taxel. The split into the 18
arrays is configuration (``HandDescription.split``), never code.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
from websockets.sync.client import ClientConnection, connect

from tacforce_ros.devices.diagnostics import ArrivalStamp
from tacforce_ros.devices.polling import PollingDriver
from tacforce_ros.hand.description import HandDescription

XELA_PORT = 5000
ALLEGRO_TAXELS = 368


class XelaFormatError(ValueError):
    """A message that is not a usable xela_server frame; the text says what is wrong."""


@dataclass(frozen=True)
class XelaMessage:
    """The decoded content of one routine frame."""

    sequence: int                 # server 'message' counter
    server_time: float            # server 'time', Unix s
    counts: np.ndarray            # (n, 3) uint16, flat order
    temperatures: np.ndarray      # (n,) float64 K, NaN when the server sends none
    model: str = ''               # the sensor's model string (XR23AHRCPP: right Allegro hand)


def _parse_counts(raw: object, n_taxels: int) -> np.ndarray:
    expected = 3 * n_taxels
    if isinstance(raw, str):
        n_values = raw.count(',') + 1
        if n_values != expected:
            raise XelaFormatError(f'data has {n_values} values, expected {expected} '
                                  f'({n_taxels} taxels x 3)')
        digits = raw.replace(',', '')
        if len(digits) != 4 * expected:
            raise XelaFormatError('data values are not all 4-digit hex')
        try:
            values = np.frombuffer(bytes.fromhex(digits), dtype='>u2')
        except ValueError as error:
            raise XelaFormatError(f'data is not hex: {error}') from None
    elif isinstance(raw, list):
        if len(raw) != expected:
            raise XelaFormatError(f'data has {len(raw)} values, expected {expected} '
                                  f'({n_taxels} taxels x 3)')
        if not all(type(v) is int and 0 <= v <= 0xFFFF for v in raw):
            raise XelaFormatError('data list holds values that are not uint16 integers')
        values = np.asarray(raw)
    else:
        raise XelaFormatError(f'data is a {type(raw).__name__}, expected a string or a list')
    return values.astype(np.uint16).reshape(n_taxels, 3)


def _parse_temperatures(raw: object, n_taxels: int) -> np.ndarray:
    if raw is None:
        return np.full(n_taxels, np.nan)
    try:
        values = np.asarray(raw.split(',') if isinstance(raw, str) else raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise XelaFormatError('temp is not a list of numbers') from None
    if values.shape != (n_taxels,):
        raise XelaFormatError(f'temp has shape {values.shape}, expected ({n_taxels},)')
    return values


def parse_message(text: str | bytes, sensor_key: str = '1',
                  n_taxels: int = ALLEGRO_TAXELS) -> XelaMessage | None:
    """Decode one frame; None for the welcome frame; XelaFormatError for anything unusable."""
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise XelaFormatError(f'not JSON: {error}') from None
    if not isinstance(doc, dict):
        raise XelaFormatError(f'frame is a JSON {type(doc).__name__}, expected an object')
    kind = doc.get('type')
    if kind == 'welcome' or doc.get('message') == 'Welcome':
        return None
    if kind != 'routine':
        raise XelaFormatError(f'frame type {kind!r}, expected "routine"')
    sensor = doc.get(sensor_key)
    if not isinstance(sensor, dict):
        raise XelaFormatError(f'no sensor {sensor_key!r} in frame')
    if sensor.get('taxels') != n_taxels:
        raise XelaFormatError(f'sensor {sensor_key!r} reports {sensor.get("taxels")} taxels, '
                              f'expected {n_taxels}')
    sequence, server_time = doc.get('message'), doc.get('time')
    if type(sequence) is not int or not isinstance(server_time, (int, float)):
        raise XelaFormatError('frame lacks an integer "message" counter or a numeric "time"')
    return XelaMessage(sequence, float(server_time), _parse_counts(sensor.get('data'), n_taxels),
                       _parse_temperatures(sensor.get('temp'), n_taxels),
                       str(sensor.get('model', '')))


def welcome_message(version: str = '1.8.0') -> str:
    return json.dumps({'message': 'Welcome', 'type': 'welcome', 'version': version})


def routine_message(sequence: int, counts: np.ndarray, temperatures: np.ndarray,
                    server_time: float, model: str = 'XR23AHRCPP', sensor_key: str = '1',
                    version: str = '1.8.0', handedness: str = 'right') -> str:
    """A v1.8 routine frame with one sensor (hex ``data``, decimal ``integer``, ``temp`` K)."""
    flat = np.asarray(counts, dtype=np.uint16).reshape(-1)
    hex_digits = flat.astype('>u2').tobytes().hex().upper()
    sensor = {'time': server_time, 'sensor': sensor_key, 'model': model,
              'taxels': flat.size // 3,
              'data': ','.join(hex_digits[i:i + 4] for i in range(0, len(hex_digits), 4)),
              'integer': ','.join(map(str, flat.tolist())),
              'temp': np.round(np.asarray(temperatures, dtype=np.float64), 2).tolist(),
              'handedness': handedness}
    return json.dumps({'message': sequence, 'time': server_time, 'sensors': 1,
                       'type': 'routine', 'version': version, 'sendtime': time.time(),
                       sensor_key: sensor})


@dataclass(frozen=True)
class XelaFrame:
    """One hand reading: ``counts`` (368, 3) uint16 in flat order, ``arrays`` the same split
    per taxel array (config order, empty without a hand description)."""

    sequence: int
    server_time: float
    counts: np.ndarray
    temperatures: np.ndarray
    stamp: ArrivalStamp
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    model: str = ''               # the sensor's model string, as the server reports it


@dataclass(frozen=True)
class XelaConfig:
    """Server address and reconnect policy: waits grow from ``reconnect_initial`` by
    ``reconnect_factor`` up to ``reconnect_max`` s; ``max_attempts`` consecutive failures
    (0 = never give up) end the client with ConnectionError."""

    url: str = f'ws://127.0.0.1:{XELA_PORT}'
    sensor_key: str = '1'
    n_taxels: int = ALLEGRO_TAXELS
    open_timeout: float = 1.0
    # The closing handshake's wait for the server (the library waits 10 s): a server that
    # stopped answering must not hold a driver that is asked to stop.
    close_timeout: float = 0.5
    reconnect_initial: float = 0.05
    reconnect_factor: float = 2.0
    reconnect_max: float = 2.0
    max_attempts: int = 0
    stale_after: float = 0.05


class XelaClient(PollingDriver[XelaFrame]):
    """Receives xela_server frames, stamping each on arrival; reconnects on its own."""

    def __init__(self, config: XelaConfig, hand: HandDescription | None = None) -> None:
        super().__init__(config.stale_after)
        if hand is not None and hand.n_taxels != config.n_taxels:
            raise ValueError(f'hand description has {hand.n_taxels} taxels, the XELA config '
                             f'{config.n_taxels}')
        self.config = config
        self.hand = hand
        self._names = [a.name for a in hand.arrays] if hand is not None else []
        self._connection: ClientConnection | None = None
        self._ever_connected = False
        self._failures = 0
        self._next_attempt = 0.0
        self._last_sequence: int | None = None

    @property
    def connected(self) -> bool:
        return self._connection is not None

    def _connect(self) -> None:
        try:
            self._connection = connect(self.config.url, open_timeout=self.config.open_timeout,
                                       close_timeout=self.config.close_timeout,
                                       max_size=None, compression=None, legacy=True)
        except (OSError, TimeoutError, InvalidHandshake, InvalidURI) as error:
            self._failures += 1
            self.diagnostics.last_error = f'connect to {self.config.url} failed: {error}'
            if self.config.max_attempts and self._failures >= self.config.max_attempts:
                raise ConnectionError(f'gave up after {self._failures} attempts: '
                                      f'{self.diagnostics.last_error}') from error
            delay = min(self.config.reconnect_max,
                        self.config.reconnect_initial
                        * self.config.reconnect_factor ** (self._failures - 1))
            self._next_attempt = time.monotonic() + delay
            return
        if self._ever_connected:
            self.diagnostics.add(reconnects=1)
        self._ever_connected = True
        self._failures = 0
        self._last_sequence = None       # a restarted server counts from scratch

    def _disconnect(self, reason: str) -> None:
        if self._connection is not None:
            self._connection.close()
        self._connection = None
        self.diagnostics.last_error = reason
        self._next_attempt = time.monotonic() + self.config.reconnect_initial

    def _receive(self, timeout: float) -> list[XelaFrame]:
        if self._connection is None:
            wait = self._next_attempt - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, timeout))
                return []
            self._connect()
            if self._connection is None:
                return []
        frames = []
        wait = timeout
        while True:
            try:
                text = self._connection.recv(timeout=wait)
            except TimeoutError:
                return frames
            except ConnectionClosed as error:
                self._disconnect(f'server closed the connection: {error}')
                return frames
            wait = 0.0
            stamp = ArrivalStamp.now()
            self.diagnostics.note_received(stamp.monotonic)
            try:
                message = parse_message(text, self.config.sensor_key, self.config.n_taxels)
            except XelaFormatError as error:
                self.diagnostics.note_malformed(str(error))
                continue
            if message is not None and self._in_sequence(message.sequence):
                frames.append(self._frame(message, stamp))

    def _in_sequence(self, sequence: int) -> bool:
        if self._last_sequence is not None:
            delta = sequence - self._last_sequence
            if delta <= 0:
                self.diagnostics.add(reordered=1, dropped=1)
                return False
            self.diagnostics.add(gaps=delta - 1)
        self._last_sequence = sequence
        return True

    def _frame(self, message: XelaMessage, stamp: ArrivalStamp) -> XelaFrame:
        arrays = (dict(zip(self._names, self.hand.split(message.counts)))
                  if self.hand is not None else {})
        return XelaFrame(message.sequence, message.server_time, message.counts,
                         message.temperatures, stamp, arrays, message.model)

    def _shutdown(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None
