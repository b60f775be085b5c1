// placeholder: the mesher is being written
