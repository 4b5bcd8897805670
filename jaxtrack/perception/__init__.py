"""Perception: depth point clouds to likelihoods and orientation (seed 000 depth tracker), colour
histograms and their Bhattacharyya likelihood (seed 000's colour tracker), laser
scans to legs and people (seed 004 leg detector), RGB-D point clouds to people (seed 001: voxel
grid, ground plane, Euclidean clustering, head sub-clustering, HOG confidence), ceiling cameras'
person detections through ground-plane homographies (seed 003), and the sensing step of a
person-following robot (laser and RGB-D people into the estimators' frame)."""

from jaxtrack.perception import (ceiling_camera, colour_histogram, depth, euclidean_clustering,
                                 ground_plane, head_subclustering, hog, legs, rgbd_people, sensing,
                                 voxel_grid)

__all__ = ["ceiling_camera", "colour_histogram", "depth", "euclidean_clustering", "ground_plane",
           "head_subclustering", "hog", "legs", "rgbd_people", "sensing", "voxel_grid"]
