"""The application layer (informative, outside the spec): what the command-line programs and the
library API share around the codec: argument types and exit statuses, atomic file output,
progress reporting, size reports. Nothing here affects a decoded scene."""
