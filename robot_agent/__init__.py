"""The robot daemon (paper §5): maps step by step, keeps the Robot DB, applies control messages."""
