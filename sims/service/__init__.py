"""The service-robot scene (seeds 002 and 003): a robot in a flat among people who walk, stand,
sit on the couch watching TV and wait for a hand-over; ceiling cameras, the robot's RGB-D and
laser, a sequential multi-sensor NN-JPDA tracker, person costmaps, a grid planner, and seed
002's person-interest approach."""
