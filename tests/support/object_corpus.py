"""Hand-labelled stage-1 scene descriptions for the object reader (rules ``objects@lightemma/1``,
docs/definitions.md#described-objects).

Each entry is ``(text, labels, counts)``: ``labels`` maps a class to what a careful reader takes from the text —
``affirmed`` (the text says one is there), ``negated`` (says none is there), ``hedged`` (only a caution or a
possibility: not a claim) — every class not named is ``not_mentioned``; ``counts`` maps a class to the number the
text states for it (classes not named: no number stated, -1). Styles are those real models write: terse lists,
verbose paragraphs, Markdown, with negations, hedges and places named after objects ("bus stop").
"""

from __future__ import annotations

A, N, H = "affirmed", "negated", "hedged"

# fmt: off
CORPUS: list[tuple[str, dict[str, str], dict[str, int]]] = [
    # ---- terse
    ("A pedestrian is crossing the road ahead.", {"pedestrian": A}, {"pedestrian": 1}),
    ("Two cars ahead, one truck on the left.", {"car": A, "truck": A}, {"car": 2, "truck": 1}),
    ("Empty road. No vehicles or pedestrians.", {"pedestrian": N}, {}),
    ("Cars parked on both sides.", {"car": A}, {}),
    ("A cyclist rides in the bike lane on the right.", {"cyclist": A}, {"cyclist": 1}),
    ("Traffic cones block the right lane.", {"traffic_cone": A}, {}),
    ("A bus is stopped at the bus stop on the right.", {"bus": A}, {"bus": 1}),
    ("Three pedestrians wait at the crosswalk.", {"pedestrian": A}, {"pedestrian": 3}),
    ("The traffic light ahead is red.", {"traffic_light": A}, {}),
    ("A motorcycle overtakes on the left.", {"motorcycle": A}, {"motorcycle": 1}),
    ("Construction barriers narrow the road.", {"barrier": A}, {}),
    ("A white van is parked on the right.", {"car": A}, {"car": 1}),
    # ---- verbose paragraphs
    ("The image shows a multi-lane urban road on a sunny day. A silver sedan is driving ahead of the ego vehicle in "
     "the same lane, and a delivery truck is parked on the right side of the street. There are no pedestrians or "
     "cyclists visible. Lane markings are clear and the traffic lights at the intersection ahead are green.",
     {"car": A, "truck": A, "pedestrian": N, "cyclist": N, "traffic_light": A}, {"car": 1, "truck": 1}),
    ("The scene depicts a residential street lined with trees. Several cars are parked along the curb on both "
     "sides. A woman is walking a dog on the left sidewalk. No traffic lights or signs are visible.",
     {"car": A, "pedestrian": A, "traffic_light": N, "traffic_sign": N}, {"pedestrian": 1}),
    ("We are approaching an intersection. A city bus is turning right in front of us, and a group of people is "
     "waiting at the pedestrian crossing. The road is wet.",
     {"bus": A, "pedestrian": A}, {"bus": 1}),
    ("The ego vehicle is on a highway. There are a few trucks in the right lanes and one car in the left lane. The "
     "road is clear of pedestrians.",
     {"truck": A, "car": A, "pedestrian": N}, {"car": 1}),
    ("A construction zone is ahead: orange traffic cones and concrete barriers separate the work area from the "
     "open lane. A construction worker stands beside the cones.",
     {"traffic_cone": A, "barrier": A, "pedestrian": A}, {"pedestrian": 1}),
    ("The road is empty except for a parked car on the right. It is night, and the street lights are on.",
     {"car": A}, {"car": 1}),
    ("A cyclist and a pedestrian share the sidewalk on the right; a stop sign stands at the corner.",
     {"cyclist": A, "pedestrian": A, "traffic_sign": A}, {"cyclist": 1, "pedestrian": 1, "traffic_sign": 1}),
    ("Two motorcyclists wait at the red light next to a taxi.",
     {"motorcycle": A, "traffic_light": A, "car": A}, {"motorcycle": 2, "car": 1}),
    # ---- Markdown / lists
    ("**Vehicles:** a black SUV ahead, a pickup truck oncoming.\n**Pedestrians:** none.\n**Traffic lights:** green.",
     {"car": A, "truck": A, "pedestrian": N, "traffic_light": A}, {"car": 1, "truck": 1}),
    ("- Vehicles: two sedans ahead\n- Pedestrians: none visible\n- Cyclists: none",
     {"car": A, "pedestrian": N, "cyclist": N}, {"car": 2}),
    ("1. A bus on the left\n2. A pedestrian near the curb\n3. No traffic cones",
     {"bus": A, "pedestrian": A, "traffic_cone": N}, {"bus": 1, "pedestrian": 1}),
    # ---- hedges and cautions (no claim)
    ("The road ahead is clear. Watch for pedestrians who may step out from between parked cars.",
     {"pedestrian": H, "car": H}, {}),
    ("A car is ahead. Be cautious of any cyclists near the intersection.", {"car": A, "cyclist": H}, {"car": 1}),
    ("There may be pedestrians behind the bus.", {"pedestrian": H, "bus": H}, {}),
    ("Possible pedestrian on the left sidewalk, partially hidden by a tree.", {"pedestrian": H}, {}),
    ("A truck is parked ahead; pedestrians might cross in front of it.", {"truck": A, "pedestrian": H}, {"truck": 1}),
    # ---- places and markings named after objects
    ("The lane ends at a bus stop; there is a pedestrian crossing ahead and a bike lane on the right.", {}, {}),
    ("There is a car park entrance on the right.", {}, {}),
    ("The ego car is in the middle lane; our car follows a truck.", {"truck": A}, {"truck": 1}),
    ("There is a no parking sign on the right.", {"traffic_sign": A}, {"traffic_sign": 1}),
    # ---- contrasts and post-negation
    ("No pedestrians are present, but a cyclist rides ahead.", {"pedestrian": N, "cyclist": A}, {"cyclist": 1}),
    ("Pedestrians are not visible; a bus approaches from the left.", {"pedestrian": N, "bus": A}, {"bus": 1}),
    ("There are no other vehicles, and a pedestrian stands at the corner.",
     {"pedestrian": A}, {"pedestrian": 1}),
    ("Without any traffic around, the street looks quiet apart from two parked cars.", {"car": A}, {"car": 2}),
    # ---- affirmed and negated in one text: affirmed (a claim that one is there)
    ("A pedestrian waits on the left; no pedestrians on the right.", {"pedestrian": A}, {"pedestrian": 1}),
    # ---- anaphora does not add to counts
    ("A car is ahead. The car is braking.", {"car": A}, {"car": 1}),
    ("Two cars are ahead and a car is on the left.", {"car": A}, {"car": 3}),
    ("A person is jogging on the sidewalk. Children are playing nearby.", {"pedestrian": A}, {}),
]
# fmt: on
