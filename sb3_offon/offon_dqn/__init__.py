from sb3_offon.offon_dqn.offon_dqn import OffOnDQN
from sb3_offon.offon_dqn.policies import CnnPolicy, MlpPolicy, MultiInputPolicy

__all__ = ["CnnPolicy", "MlpPolicy", "MultiInputPolicy", "OffOnDQN"]
