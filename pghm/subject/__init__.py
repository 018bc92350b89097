"""The on-disk subject format (see docs/data.md): :mod:`~pghm.subject.writer`, the lazy
:mod:`~pghm.subject.reader` and :mod:`~pghm.subject.checker`, over :mod:`~pghm.subject.format`.

A subject is one folder:

    images/NNNNNN.png   RGB, white background, image i named with six digits
    masks/NNNNNN.png    8-bit grey alpha matte: 255 on the person, 0 off it, on the outline
                        the covered fraction (a binary 0/255 mask is a valid matte); the
                        person is the pixels >= 128
    cameras.npz         K (n, 3, 3), world_to_camera (n, 4, 4) (OpenCV axes: x right,
                        y down, z forward), height (n,), width (n,); optional
                        frame_index (n,), view_index (n,) (multi-view captures)
    poses.npz           rotations (n, J, 3) axis-angle per bone in rest-aligned axes,
                        translation (n, 3) root translation in metres (pghm.body.pose),
                        shape (S,), body (backend name), bone_names (J,); optional
                        rotations_true, translation_true (exact poses, synthetic data)
    splits.json         {"train": [image indices], "test": [...], ...}
    meta.json           {"format": "pghm-subject", "format_version": 1, ...}

A dataset (the prior's training set) is a folder of subject folders with a meta.json
{"format": "pghm-dataset", "format_version": 1, "subjects": [folder names], ...}.

:class:`Subject` keeps the small arrays in memory and reads an image only when its
:class:`Frame` is requested. :func:`check` streams through a subject or dataset, decoding
one image or mask at a time.
"""

from pghm.subject.checker import Problem, check, check_subject, count_images
from pghm.subject.format import ALL_SPLIT, SubjectArrays, image_name, stated_pose_noise
from pghm.subject.reader import Dataset, Frame, Subject, SubjectSplit, is_dataset, open_subjects, read_mask, read_rgb
from pghm.subject.writer import npz_bytes, write_dataset_meta, write_image, write_subject

__all__ = [
    "ALL_SPLIT",
    "Dataset",
    "Frame",
    "Problem",
    "Subject",
    "SubjectArrays",
    "SubjectSplit",
    "check",
    "check_subject",
    "count_images",
    "image_name",
    "is_dataset",
    "npz_bytes",
    "open_subjects",
    "read_mask",
    "read_rgb",
    "stated_pose_noise",
    "write_dataset_meta",
    "write_image",
    "write_subject",
]
