"""rosbag2 calibration bags without ROS: the layout (topics, QoS, session metadata, typestore,
message builders: layout.py), a crash-tolerant writer (writer.py) and the reader (reader.py).
The names other modules use are imported here, so `bagio.read_messages` and the like read as
one interface."""
from tacforce_ros.bagio.layout import (CUSTOM_DATA_PREFIX, METADATA_KEYS, ROS_DISTRO,
                                       TOPIC_TYPES, BagError, calibration_sample, header,
                                       joint_state, kit, offered_qos, session_message,
                                       session_metadata, tactile_hand, typestore, wrench_stamped)
from tacforce_ros.bagio.reader import (bag_files, load_metadata, mcap_complete, read_messages,
                                       read_session_metadata, reader_counts)
from tacforce_ros.bagio.writer import (CHUNK_BYTES, CalibrationBagWriter, FileRecord, TopicRecord,
                                       bag_metadata, mcap_writer, topic_records, write_metadata)

__all__ = ['CUSTOM_DATA_PREFIX', 'METADATA_KEYS', 'ROS_DISTRO', 'TOPIC_TYPES', 'BagError',
           'calibration_sample', 'header', 'joint_state', 'kit', 'offered_qos', 'session_message',
           'session_metadata', 'tactile_hand', 'typestore', 'wrench_stamped', 'bag_files',
           'load_metadata', 'mcap_complete', 'read_messages', 'read_session_metadata',
           'reader_counts', 'CHUNK_BYTES', 'CalibrationBagWriter', 'FileRecord', 'TopicRecord',
           'bag_metadata', 'mcap_writer', 'topic_records', 'write_metadata']
