"""Recording: rosbag2 bags (Jazzy, MCAP storage) that ros2 bag, Foxglove and rosbags read.

``BagWriter`` writes, ``read_messages``/``read_custom_data``/``read_attachments`` read our
bags back, ``recover`` repairs a damaged bag. Format and crash behaviour: docs/bag-format.md.
"""

from .bag import BagError, BagWriter, DEFAULT_CHUNK_SIZE
from .integrity import BagDamageError
from .read import read_attachments, read_custom_data, read_messages
from .recover import recover, RecoveryReport

__all__ = ['BagDamageError', 'BagError', 'BagWriter', 'DEFAULT_CHUNK_SIZE', 'read_attachments',
           'read_custom_data', 'read_messages', 'recover', 'RecoveryReport']
