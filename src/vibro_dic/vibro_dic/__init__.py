"""Sub-pixel digital image correlation (ZNCC + IC-GN) of ball and structure; frame source and tracker nodes."""
