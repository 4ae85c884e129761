"""What a browser may send a viewer's viser server, checked before viser sees it.

viser 1.1.1 trusts its clients: a ``GuiUpdateMessage`` sets whatever attribute of a widget it names (``update_cb``
disables a button for everyone), a file-upload message into a text box makes its value an ``UploadedFile``, a share
request starts a tunnel process, any web page may open the websocket, and one message may be 50 MB. No fork of
viser is needed to close these: every incoming message passes through ``WebsockServer._handle_incoming_message`` (the
server's handlers) and ``WebsockClientConnection._handle_incoming_message`` (the page's own handlers), both looked up
on the instance, so :func:`guard_server` wraps them, and a connect callback put first in the websocket server's list
checks the page's ``Origin`` (``_live_connections`` holds the raw connection before any callback runs) and caps its
message size.

Accepted: the message types viser's own client sends for viewing and widgets (camera, GUI values, button holds,
clicks, drags, render and local-storage answers, commands). A ``GuiUpdateMessage`` may change only ``value``, with
the widget's own type: a bool for checkboxes, ``True`` for buttons, finite numbers within the widget's min / max, text
of at most ``MAX_TEXT_CHARS``, one of a dropdown's options, tuples of the same length. Refused (dropped, counted, logged
once per client): uploads, share requests, form messages, any other type, and everything from a page whose Origin is
not allowed (its connection is closed). A refused message reaches no handler, so one page cannot break another's panel.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import math
import socket
import threading
from collections import Counter
from typing import Any, Dict, Iterable, Optional, Set
from urllib.parse import urlsplit

from viser import _messages as vm

from .safe_text import MAX_TEXT_CHARS

log = logging.getLogger(__name__)

MAX_MESSAGE_BYTES = 1 << 20
"""Largest websocket message a page may send (viser allows 50 MB); camera and widget messages take a few hundred
bytes."""

ACCEPTED = (
    vm.ViewerCameraMessage, vm.GuiUpdateMessage, vm.GuiButtonHoldMessage, vm.ScenePointerMessage,
    vm.SceneNodeClickMessage, vm.SceneNodeDragMessage, vm.TransformControlsUpdateMessage,
    vm.TransformControlsDragStartMessage, vm.TransformControlsDragEndMessage, vm.GetRenderResponseMessage,
    vm.LocalStorageGetItemResponseMessage, vm.CommandTriggerMessage,
)
LOCAL_HOSTS = {"localhost", "127.0.0.1", "::1"}


def _finite_numbers(values: Iterable[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)


def update_refusal(handle: Any, updates: Any) -> Optional[str]:
    """Why a ``GuiUpdateMessage``'s ``updates`` for ``handle`` is refused, or None when it is a valid value."""
    from viser import GuiButtonHandle, GuiDropdownHandle

    if not isinstance(updates, dict) or set(updates) != {"value"}:
        return f"only 'value' may change, not {sorted(map(str, updates)) if isinstance(updates, dict) else updates!r}"
    value = updates["value"]
    impl = handle._impl
    current, props = impl.value, getattr(impl, "props", None)
    if isinstance(handle, GuiButtonHandle):
        return None if value is True else "a button click must be true"
    if isinstance(current, bool):
        return None if isinstance(value, bool) else "expected true or false"
    if isinstance(current, (int, float)):
        if not _finite_numbers([value]):
            return "expected a finite number"
        lo, hi = getattr(props, "min", None), getattr(props, "max", None)
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            return f"{value} is outside [{lo}, {hi}]"
        return None
    if isinstance(current, str):
        if not isinstance(value, str):
            return "expected text"
        if len(value) > MAX_TEXT_CHARS:
            return f"text of {len(value)} characters (at most {MAX_TEXT_CHARS})"
        if isinstance(handle, GuiDropdownHandle) and value not in tuple(handle.options):
            return "not one of the dropdown's options"
        return None
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)) or len(value) != len(current):
            return f"expected {len(current)} values"
        if all(isinstance(c, str) for c in current):
            return None if all(isinstance(v, str) and len(v) <= MAX_TEXT_CHARS for v in value) else "expected text"
        return None if _finite_numbers(value) else "expected finite numbers"
    return f"this widget's value ({type(current).__name__}) cannot be set by a page"


def origin_allowed(origin: Optional[str], host_header: Optional[str], bound_host: str,
                   extra: Iterable[str] = ()) -> bool:
    """A page may connect when its ``Origin`` is a local address (localhost, 127.0.0.1, ::1), the host the server is
    bound to, one of ``extra``, or the address the page itself was loaded from (same origin) when that is an IP
    address or this machine's name (never another DNS name: a rebinding attack serves its page from such a name).
    No Origin (not a browser, which always sends one): allowed, since such a client could send any Origin anyway."""
    if origin is None:
        return True
    try:
        host = (urlsplit(origin).hostname or "").lower()
    except ValueError:
        return False
    if not host:
        return False
    if host in LOCAL_HOSTS or host in {h.lower() for h in extra}:
        return True
    if bound_host not in ("0.0.0.0", "::", "") and host == bound_host.lower():
        return True
    try:
        served_from = (urlsplit(f"//{host_header}").hostname or "").lower() if host_header else ""
    except ValueError:
        served_from = ""
    if host != served_from:
        return False
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return host in {socket.gethostname().lower(), socket.getfqdn().lower()}


class ServerGuard:
    """The checks installed on one viser server (see the module docstring); ``refused`` counts what was dropped."""

    def __init__(self, server: Any, bound_host: str, extra_origins: Iterable[str] = (),
                 max_connections: Optional[int] = None) -> None:
        self.server = server
        self.max_connections = max_connections
        self.bound_host = bound_host
        self.extra_origins = tuple(extra_origins)
        self.refused: Counter = Counter()  # reason -> count
        self.refused_clients: Set[int] = set()  # connections closed for their Origin
        self._logged: Set[int] = set()
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ messages
    def check(self, client_id: int, message: Any, gui: Any) -> bool:
        """Whether ``message`` from ``client_id`` may reach the handlers of ``gui``'s scope (None: the page's GuiApi,
        looked up when needed). A message too malformed to check is refused."""
        try:
            reason = self._refusal(client_id, message, gui)
        except Exception as err:  # noqa: BLE001 - e.g. a list where a uuid belongs
            reason = f"malformed {type(message).__name__}: {type(err).__name__}"
        if reason is None:
            return True
        with self._lock:
            self.refused[reason.split(":")[0]] += 1
            first = client_id not in self._logged
            self._logged.add(client_id)
        (log.warning if first else log.debug)("client %s: message dropped (%s)", client_id, reason)
        return False

    def _refusal(self, client_id: int, message: Any, gui: Any) -> Optional[str]:
        reason = None
        if client_id in self.refused_clients:
            reason = "origin not allowed"
        elif not isinstance(message, ACCEPTED):
            reason = f"{type(message).__name__} not accepted"
        elif isinstance(message, vm.ViewerCameraMessage):
            if not _finite_numbers([*message.wxyz, *message.position, *message.look_at, *message.up_direction,
                                    message.fov, message.near, message.far]):
                reason = "camera with non-finite numbers"
        elif isinstance(message, vm.GuiUpdateMessage):
            if gui is None:
                client = self.server._connected_clients.get(client_id)
                gui = None if client is None else client.gui
            handles: Dict[str, Any] = {} if gui is None else gui._gui_input_handle_from_uuid
            handle = handles.get(message.uuid)
            if handle is not None:  # unknown here: viser ignores it in this scope too
                why = update_refusal(handle, message.updates)
                if why is not None:
                    reason = f"GuiUpdateMessage refused: {why}"
        return reason

    # ------------------------------------------------------------------ connections
    async def on_connect(self, conn: Any) -> None:
        """First connect callback of the websocket server: Origin check, message size cap, the page's own handlers
        wrapped."""
        ws = self.server._websock_server
        connection = ws._live_connections.get(conn.client_id)
        if connection is not None:
            try:
                connection.protocol.max_message_size = MAX_MESSAGE_BYTES
            except AttributeError:  # another websockets version: viser's 50 MB cap stays
                log.debug("could not cap the message size of client %s", conn.client_id)
            headers = connection.request.headers if connection.request is not None else {}
            if self.max_connections is not None and len(ws._live_connections) > self.max_connections:
                self.refused_clients.add(conn.client_id)  # each page is sent the whole splat: bounded
                log.warning("refused a page: %d connections open, the limit", self.max_connections)
                asyncio.get_running_loop().create_task(connection.close(1013, "too many pages open; try later"))
            elif not origin_allowed(headers.get("Origin"), headers.get("Host"), self.bound_host, self.extra_origins):
                self.refused_clients.add(conn.client_id)
                log.warning("refused a page from Origin %r (not this viewer's address)", headers.get("Origin"))
                asyncio.get_running_loop().create_task(connection.close(1008, "origin not allowed"))
        inner = conn._handle_incoming_message

        async def guarded(client_id: int, message: Any) -> None:
            if self.check(client_id, message, None):
                await inner(client_id, message)

        conn._handle_incoming_message = guarded

    async def on_disconnect(self, conn: Any) -> None:
        self.refused_clients.discard(conn.client_id)
        self._logged.discard(conn.client_id)


def guard_server(server: Any, bound_host: str, extra_origins: Iterable[str] = (),
                 hide_share_button: bool = True, max_connections: Optional[int] = None) -> ServerGuard:
    """Install :class:`ServerGuard` on a running ``viser.ViserServer`` and turn share requests off (and the share
    button, with ``hide_share_button``: viser's ``configure_theme`` resets the whole theme, so ns-viewer, whose theme
    nerfstudio sets, keeps the button, which then does nothing). ``max_connections``: websockets open at once (each
    page is sent the whole splat); more are closed at once. Call it before any page can connect."""
    guard = ServerGuard(server, bound_host, extra_origins, max_connections)
    ws = server._websock_server
    inner = ws._handle_incoming_message

    async def guarded(client_id: int, message: Any) -> None:
        if guard.check(client_id, message, server.gui):
            await inner(client_id, message)

    ws._handle_incoming_message = guarded
    ws._client_connect_cb.insert(0, guard.on_connect)
    ws._client_disconnect_cb.append(guard.on_disconnect)
    for cls in (vm.ShareUrlRequest, vm.ShareUrlDisconnect):  # dropped by the check too; no handler left to run
        ws._incoming_handlers.pop(cls, None)
    try:
        if hide_share_button:
            server.gui.configure_theme(show_share_button=False)
    except Exception:  # noqa: BLE001 - the requests are refused whatever the page shows
        log.debug("hiding viser's share button failed", exc_info=True)
    return guard
