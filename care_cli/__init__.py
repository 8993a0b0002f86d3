"""The ``care`` command-line program: sits on top and imports the stages."""
