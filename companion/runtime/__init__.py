"""The live companion on a real link: link management (:mod:`.link`), transports, the asyncio runtime."""

from companion.mavlink.link import LinkStatus, MavlinkLink
from companion.runtime.runner import Runtime

__all__ = ["LinkStatus", "MavlinkLink", "Runtime"]
