"""The vehicle behind LCM (pydrake-free parts): message checks (watchdog), image messages, the
scenario's hardware settings, a localhost LCM ``tcpq`` hub, drive-log replay and ROS 2 bags."""
