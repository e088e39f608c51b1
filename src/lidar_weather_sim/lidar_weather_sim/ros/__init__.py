"""Thin rclpy adapters: parameters, topics, QoS and message conversion only.

Everything here imports rclpy; the library modules one level up do not.
"""
