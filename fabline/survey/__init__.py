"""The survey stage: AprilTag photogrammetry of the built shell, measured node by node against the design."""

from fabline.survey.calibrate import BoardSpec, board_image, calibrate, write_board
from fabline.survey.camera import Camera, camera_from_dict, camera_to_dict, load_camera, save_camera
from fabline.survey.detect import (TagDetection, TagPose, detect_expected_tags, detect_tags, read_gray, refine_corners,
                                   tag_object_points, tag_pose)
from fabline.survey.measure import MeasureOptions, detect_photos, list_photos, measure_survey
from fabline.survey.reconstruct import Observation, Reconstruction, bundle_adjust
from fabline.survey.register import register, rigid_fit
from fabline.survey.simulate import SyntheticSpec, render_plane_photo, saddle_network, sag_field, simulate_survey
from fabline.survey.tagmap import (TagMap, check_tag_map, load_tag_map, make_tag_map, save_tag_map, tag_image,
                                   tagmap_from_dict, tagmap_to_dict, write_tag_sheets)

__all__ = [
    "BoardSpec", "Camera", "MeasureOptions", "Observation", "Reconstruction", "SyntheticSpec", "TagDetection", "TagMap", "TagPose",
    "board_image", "bundle_adjust", "calibrate", "camera_from_dict", "camera_to_dict", "check_tag_map", "detect_expected_tags",
    "detect_photos", "detect_tags", "list_photos", "load_camera", "load_tag_map", "make_tag_map", "measure_survey", "read_gray",
    "refine_corners", "register", "render_plane_photo", "rigid_fit", "saddle_network", "sag_field", "save_camera",
    "save_tag_map", "simulate_survey", "tag_image", "tag_object_points", "tag_pose", "tagmap_from_dict",
    "tagmap_to_dict", "write_board", "write_tag_sheets",
]
