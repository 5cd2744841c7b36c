"""What a recording lost, and where: the device's own counters (STATS) at the start and at
the end of the recorded span, and the host's.

* ``device_queue``: snapshots the firmware's bounded telemetry queue dropped (the oldest
  first) because they were produced faster than the link took them
  (``loop.telemetry_dropped``);
* ``device_link``: frames the firmware dropped from this session's send queue because
  the host did not read fast enough (``session.tx_dropped``);
* ``link``: frames missing from the sequence numbers the host received, beyond those the
  firmware dropped itself (lost on the wire, or corrupted: ``crc_errors``);
* ``host``: snapshots this host received but could not keep (its queue overflowed).

The device's counters cover the span between the two STATS, so the first is taken right
before recording, the last right after; a device that stopped answering gives no end
counters, and the summary says so.
"""
from __future__ import annotations

DEVICE_KEYS = {"device_queue": "loop.telemetry_dropped", "device_link": "session.tx_dropped"}


def device_counters(dev) -> dict | None:
    """The device's drop counters now (STATS), or None if it does not answer."""
    from .device import HostctlError
    try:
        st = dev.stats()
    except HostctlError:
        return None
    return {k: int(st.get(key, 0) or 0) for k, key in DEVICE_KEYS.items()}


def host_counters(dev) -> dict:
    lc = dev.link_counters()
    return dict(lost=int(lc["lost"]), crc_errors=int(lc.get("crc_errors", 0)),
                host=int(lc.get("telemetry_overflow", 0)))


def span(dev_before: dict | None, dev_after: dict | None, host_before: dict,
         host_after: dict) -> dict:
    """Drops over the recorded span by place; ``device_known`` False if the device's
    counters are missing at either end (then its drops are unknown, not zero)."""
    d = {k: host_after[k] - host_before[k] for k in host_before}
    known = dev_before is not None and dev_after is not None
    dev = {k: dev_after[k] - dev_before[k] for k in DEVICE_KEYS} if known else {}
    return dict(device_known=known,
                device_queue=dev.get("device_queue", 0), device_link=dev.get("device_link", 0),
                link=max(0, d["lost"] - dev.get("device_link", 0)), crc_errors=d["crc_errors"],
                host=d["host"])


def summary(drops: dict, snapshots: int) -> tuple[str, bool]:
    """The summary's words on drops and whether they call for a warning: every non-zero
    count by place, and what share of the span's snapshots they are."""
    places = [("device queue", drops["device_queue"]), ("device send queue", drops["device_link"]),
              ("link", drops["link"]), ("CRC errors", drops["crc_errors"]), ("host", drops["host"])]
    lost = drops["device_queue"] + drops["device_link"] + drops["link"] + drops["host"]
    text = "lost " + ", ".join(f"{name} {n}" for name, n in places)
    if lost:
        text += f" ({lost / (lost + snapshots):.1%} of the span's snapshots missing)"
    if not drops["device_known"]:
        text += "; the device's own drops are unknown (its STATS did not answer)"
    return text, bool(lost or drops["crc_errors"] or not drops["device_known"])
