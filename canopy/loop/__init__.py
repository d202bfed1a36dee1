"""Loop closing (AGRI-SLAM §3.4): place recognition, geometric verification, pose-graph
optimisation, relocalisation."""
from canopy.loop.database import Candidate, FeatureStats, KeyframeDatabase, combined_score, l1_score
from canopy.loop.keyframe import PlaceKeyframe, describe_stereo_pair, with_bow
from canopy.loop.params import LoopParams
from canopy.loop.pose_graph import (LOOP, ODOMETRY, COVISIBILITY, PoseGraphEdge, correct_landmarks, correction_for,
                                    essential_graph_edges, optimise_pose_graph, pose_corrections)
from canopy.loop.verify import LoopConstraint, Verification, verify_candidate

__all__ = ["Candidate", "FeatureStats", "KeyframeDatabase", "combined_score", "l1_score", "PlaceKeyframe",
           "describe_stereo_pair", "with_bow", "LoopParams", "LOOP", "ODOMETRY", "COVISIBILITY", "PoseGraphEdge",
           "correct_landmarks", "correction_for", "essential_graph_edges", "optimise_pose_graph", "pose_corrections",
           "LoopConstraint", "Verification", "verify_candidate"]
