from sb3_offon.offon_dqn.offon_dqn import OffOnDQN
from sb3_offon.offon_dqn.policies import CnnPolicy, DuelingQNetwork, MlpPolicy, MultiInputPolicy, OffOnDQNPolicy

__all__ = ["CnnPolicy", "DuelingQNetwork", "MlpPolicy", "MultiInputPolicy", "OffOnDQN", "OffOnDQNPolicy"]
