"""Between server and client: the network model and the client's frame schedule (:mod:`.model`,
a simulation of delay, jitter, loss and bandwidth)."""

from splitrender.net.model import NetworkModel, Schedule

__all__ = ["NetworkModel", "Schedule"]
