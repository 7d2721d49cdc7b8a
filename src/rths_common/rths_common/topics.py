"""Topic, service and type names of the rths node graph: one place, used by every node and tool."""

#: numerical node -> compensator node (rths_msgs/msg/InterfaceDisplacement)
INTERFACE_DISPLACEMENT = '/rths/interface_displacement'
#: compensator node -> actuator bridge (rths_msgs/msg/Command)
COMMAND = '/rths/command'
#: actuator bridge -> numerical node (rths_msgs/msg/Measurement)
MEASUREMENT = '/rths/measurement'
#: every node -> anyone (rths_msgs/msg/LoopStatus)
STATUS = '/rths/status'
#: numerical node -> actuator bridge: number of steps of the run (std_msgs/msg/UInt64,
#: reliable, transient local); in realtime the bridge stops its clock after the last step
RUN_STEPS = '/rths/run_steps'
#: anyone -> actuator bridge: emergency stop (std_msgs/msg/String, the reason)
EMERGENCY_STOP = '/rths/emergency_stop'
#: service of the actuator bridge (rths_msgs/srv/EmergencyStop)
EMERGENCY_STOP_SERVICE = '/rths/emergency_stop_service'

#: Every topic a run records, with its message type (rosbag2 type names).
#: actuator bridge -> recorder: table and DTM sensor channels (rths_msgs/msg/Specimen)
SPECIMEN = '/rths/specimen'

#: compensator node -> recorder: adaptive coefficients, decimated (std_msgs/msg/Float64MultiArray)
COMPENSATOR_COEFFICIENTS = '/rths/compensator_coefficients'
#: The stability monitor's estimates [step, delay_ms, gain, error_pct, ti, level]
#: (rths_compensator.monitor; level 0 ok, 1 warn, 2 stop).
STABILITY = '/rths/stability'

#: numerical node -> recorder, once at the start: the model and the ground motion as used
#: (std_msgs/msg/String, JSON; rths_numerical.inputs), so a bag needs no other file
RUN_INPUTS = '/rths/run_inputs'
#: numerical node -> recorder, at the end: time, ground acceleration and every DOF per step
#: (std_msgs/msg/Float64MultiArray in chunks; rths_numerical.inputs)
RESPONSE = '/rths/response'
#: actuator bridge -> recorder: counts of an external servo controller's replies
#: (rths_msgs/msg/ControllerStatus)
CONTROLLER = '/rths/controller'

LOOP_TOPICS = {
    INTERFACE_DISPLACEMENT: 'rths_msgs/msg/InterfaceDisplacement',
    COMMAND: 'rths_msgs/msg/Command',
    MEASUREMENT: 'rths_msgs/msg/Measurement',
    STATUS: 'rths_msgs/msg/LoopStatus',
    SPECIMEN: 'rths_msgs/msg/Specimen',
    EMERGENCY_STOP: 'std_msgs/msg/String',
    COMPENSATOR_COEFFICIENTS: 'std_msgs/msg/Float64MultiArray',
    STABILITY: 'std_msgs/msg/Float64MultiArray',
    CONTROLLER: 'rths_msgs/msg/ControllerStatus',
    RUN_INPUTS: 'std_msgs/msg/String',
    RESPONSE: 'std_msgs/msg/Float64MultiArray',
}
