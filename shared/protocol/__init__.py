"""What the robot and the server exchange: the spelling of kernel names, versions and digests
(:mod:`shared.protocol.patterns`) and the bodies of map uploads, statuses, acknowledgements and kernel
metadata (:mod:`shared.protocol.messages`). Both sides import these; nothing here does I/O."""

from shared.protocol.messages import (
    ARTIFACT_KEY_ID_HEADER,
    ARTIFACT_SHA256_HEADER,
    ARTIFACT_SIGNATURE_HEADER,
    ARTIFACT_STAGE_HEADER,
    INT64_MAX,
    MAP_FIELDS,
    STATUS_FIELDS,
    KernelMeta,
    MapDelta,
    MapSnapshot,
    MapUpload,
    MessageAck,
    Outcome,
    RobotKernel,
    RobotStatus,
)
from shared.protocol.patterns import (
    KERNEL_NAME_MAX_LENGTH,
    KERNEL_NAME_PATTERN,
    KERNEL_NAME_RE,
    SHA256_PATTERN,
    SHA256_RE,
    VERSION_PATTERN,
    VERSION_RE,
    anchored,
)

__all__ = [
    "ARTIFACT_KEY_ID_HEADER",
    "ARTIFACT_SHA256_HEADER",
    "ARTIFACT_SIGNATURE_HEADER",
    "ARTIFACT_STAGE_HEADER",
    "INT64_MAX",
    "KERNEL_NAME_MAX_LENGTH",
    "KERNEL_NAME_PATTERN",
    "KERNEL_NAME_RE",
    "MAP_FIELDS",
    "SHA256_PATTERN",
    "SHA256_RE",
    "STATUS_FIELDS",
    "VERSION_PATTERN",
    "VERSION_RE",
    "KernelMeta",
    "MapDelta",
    "MapSnapshot",
    "MapUpload",
    "MessageAck",
    "Outcome",
    "RobotKernel",
    "RobotStatus",
    "anchored",
]
