"""Typed helpers shared by the test packages, imported by name (``from tests.support.recordings
import write_bag``) rather than handed round as fixtures.

- :mod:`tests.support.messages`: ROS 2 messages built through rosbags' type store.
- :mod:`tests.support.recordings`: the one recording writer (ROS 1 bag, rosbag2, MCAP) and the
  small RGB-D recordings made with it.
- :mod:`tests.support.frames`: synthetic frames and the loaders of the third-party frames.
- :mod:`tests.support.layouts`: frames laid out as the public RGB-D datasets ship them.
- :mod:`tests.support.encoders`: a tiny real encoder.
- :mod:`tests.support.stores`: small hand-built stores.
- :mod:`tests.support.cli`: ``care`` run in this process or in a fresh one.
- :mod:`tests.support.processes`: watching a ``care`` process from outside.
- :mod:`tests.support.faults`: the checks of the fault-injection suite.

Nothing here is a fixture: session data stays in the ``conftest.py`` files.
"""
