"""The stages' names and defaults that the commands' `--help` shows, written out here so that building the parser
imports no stage (tests/cli/test_cli_fast.py checks each against the stage's own constant)."""

MODEL_UNITS = ("cm", "ft", "in", "m", "mm")
"""fabline.model.network.UNIT_TO_MM, sorted: the units a model file can be in."""
IMPORT_FORMATS = (".json", ".obj", ".dxf", ".3dm")
"""fabline.model.importers.FORMATS: the file types `fabline import` reads."""
BOUNDARIES = ("ellipse", "diamond", "rectangle")
"""fabline.model.designs.BOUNDARIES: the parameter domains of the built-in Enneper design."""
SINGULARITY_MODES = ("joint", "slots")
"""fabline.unroll.SINGULARITY_MODES: how the unroller makes valence-6 nodes."""
STREAM_MODES = ("counting", "send-response")
"""fabline.link.streamer.MODES: the streamer's flow control."""
STOCK_BUILD_OPTIONS = "V"
"""fabline.machine.build.STOCK_BUILD.options: the $I option letters of a stock Grbl 1.1h build."""
