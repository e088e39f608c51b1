"""QoS profiles of the /tf, /tf_static and /clock writers and readers, shared by the project's nodes."""

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)  # as tf2_ros
TF_STATIC_QOS = QoSProfile(depth=100, reliability=TF_QOS.reliability, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# reliable matches best-effort and reliable readers; depth 100 as /tf: at depth 1 a tick whose first send was
# lost is overwritten by the next before it can be resent, and a busy recorder missed 1 /clock in 6000 (CI)
CLOCK_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
