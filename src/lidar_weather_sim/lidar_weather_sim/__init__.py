"""Virtual automotive LiDAR in real weather.

Subpackages, lowest layer first (``.importlinter`` enforces it: nothing
imports a layer above its own, rclpy only under ``ros``)::

    core        configuration, names, paths, point layout, seeding, workers, rotations
    sensor      profiles, scan pattern, radiometry, echo decision
    scene       meshes, materials, OpenDRIVE roads, the scene, ray casters
    regions     region plugins: protocol, cover, atmosphere
    poses       transform buffer, pose sources, pose gate
    io | scenario   bags, PointCloud2 codec, recordings | scenario files, player, World
    sim         the frame pipeline, the node's session, offline runs
    control | testing | gap   cruise control | test fixtures | the reality-gap workflow
    ros         rclpy nodes, QoS, conversions, node graphs
    experiments thesis reproductions, the closed-loop demo
    cli         the ``lidar-weather-sim`` command line
"""

__version__ = "0.1.0"
