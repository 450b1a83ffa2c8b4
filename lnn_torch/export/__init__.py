"""A trained model handed to other programs (``lnn-torch export``): its SI rigid-body functions as
``torch.export`` programs, ONNX graphs or AOTInductor libraries, each with a JSON description
(``programs``); an arm's identified links, armature and friction written back into its robot
description, MJCF or URDF (``description``: ``write_description``)."""

from .description import IdentifiedArm, WriteBack, identified_arm, write_description
from .programs import available_functions, describe, export_model, load_program, refusal, wrap

__all__ = ["export_model", "load_program", "available_functions", "describe", "refusal", "wrap",
           "write_description", "identified_arm", "IdentifiedArm", "WriteBack"]
