
from setuptools import find_packages, setup

package_name = "vibro_fit"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="vibro maintainers",
    maintainer_email="vibro@example.com",
    description=("Motion identification: structure sine fit, free-flight parabolas, impact times, per-impact COR, "
                 "friction, accelerometer impacts."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "accel_source = vibro_ros.entry:accel_source",
            "impact_detector = vibro_ros.entry:impact_detector",
            "trajectory_fitter = vibro_ros.entry:trajectory_fitter"
        ],
    },
)
