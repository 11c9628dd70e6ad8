from sb3_offon.qrdqn.qrdqn import QRDQN

__all__ = ["QRDQN"]
