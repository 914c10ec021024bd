"""Reference nodes of a live cell, each a process a lab replaces with its own: a robot under
MuJoCo physics (:mod:`.sim_robot`) and a simulated person (:mod:`.sim_human`)."""
