"""The linemap server (paper §5): kernels, robots, control messages and live maps over a REST API."""
