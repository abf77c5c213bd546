"""What the Python tests share; no test module imports another.

* ``paths``: the repository, its test data, the binaries under test.
* ``process``: the one harness for every process a test starts (armtwin, the router, stand-ins),
  and ``run_armtwin`` for one-shot CLI runs.
* ``zenoh_clients``: Python Zenoh sessions (a peer of one armtwin, a client of a router), the
  output collector, bounded queries.
* ``gateway``: the one gateway, streaming joint messages at a fixed rate.
* ``dashboard``: the service with its HTTP side on, and the tools the dashboard tests drive
  (headless Chromium, a Prometheus scraping it).
* ``pki``: a fleet's certificates (`armtwin certs`), an HTTPS server's (openssl), a client's TLS settings;
  ``secured_fleet``: the shipped router with TLS and access control, armtwin behind it, sessions
  per certificate, and the router's denials read from its log.
* ``mcap_files``: armtwin's MCAP files read back with the ``mcap`` package and
  ``mcap-ros2-support``.
* ``checks``, ``twin_reference``, ``fk_csv``: soft checks, and outputs checked against the
  references ``ur_reference`` (numpy FK) and ``ur_dynamics`` (Pinocchio).
* Generators of test inputs: ``effort_recording``, ``rtde_recording``, ``ros2_fixtures``.
* Stand-ins run as processes: ``rtde_server`` (a UR controller), ``rtde_readback`` (ur-rtde's
  client), ``ros2_driver`` (an rclpy node).

A module with a command line runs from the repository's root as
``PYTHONPATH=tests/python .venv/bin/python -m support.NAME``; the stand-ins run by path.
"""
