"""Pictures: label overlays and costmap renderings (:mod:`.overlay`), panels and sheets."""
