"""
The cell runtime: the cell's parameters, a scene of one run, and the cell itself.

``params`` declares and validates every quantity a user sets; ``scene`` loads a
single-parcel run from YAML; ``cell`` advances many parcels through the model one
period at a time and keeps the I/O image. No ROS here: the front ends call in.
"""
