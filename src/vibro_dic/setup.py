
from setuptools import find_packages, setup

package_name = "vibro_dic"

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
    description=("Sub-pixel digital image correlation (ZNCC + IC-GN) of ball and structure; "
                 "frame source and tracker nodes."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "frame_source = vibro_ros.entry:frame_source",
            "dic_tracker = vibro_ros.entry:dic_tracker"
        ],
    },
)
