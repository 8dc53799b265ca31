"""Kernel verification: what a downloaded kernel passes before the agent may run it, and the worker
processes it runs in (docs/design.md §7, §9; docs/reliability/sandbox.md).

The agent installs a kernel only after every step below succeeded, cheapest first; each refusal raises
:class:`~robot_agent.errors.KernelRejected` whose ``reason`` is what the server (and the operator) is told:

1. :mod:`~robot_agent.kernels.artifact`: the SHA-256 of the source matches the message's, and an Ed25519
   signature by a key the robot trusts covers it (unsigned code only with ``--allow-unsigned``);
2. :mod:`~robot_agent.kernels.dryrun`: the dry run (the kernel applied to what its stage would see on the
   last scans) and the conformance battery (:mod:`~robot_agent.kernels.conformance`), in a confined worker
   process with time, CPU and memory limits;
3. the kernel is then loaded (:mod:`~robot_agent.kernels.loading`) in a long-lived worker process of its
   own (:mod:`~robot_agent.kernels.worker`, confined by :mod:`~robot_agent.kernels.sandbox`), and the agent
   registers a class that forwards every call to it (:mod:`~robot_agent.kernels.proc`), over the message
   format of :mod:`~robot_agent.kernels.wire`.

The downloaded code never runs in the agent's process. Nothing here touches the database or the network.
This module imports nothing, so a worker process starts light.
"""
