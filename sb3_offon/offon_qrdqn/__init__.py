from sb3_offon.offon_qrdqn.offon_qrdqn import OffOnQRDQN

__all__ = ["OffOnQRDQN"]
