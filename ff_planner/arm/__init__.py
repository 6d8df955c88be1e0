"""Arms from a URDF plus a cell file: checks, Pinocchio model, Eq. 9 at every joint, simulation."""
