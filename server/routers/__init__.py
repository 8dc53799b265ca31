"""One router per resource of the REST API under ``/api/v1`` (docs/design.md §7)."""
